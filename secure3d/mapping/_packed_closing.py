"""Closing and greedy box merge of a voxel set on a bit-packed grid (64 cells per word).

:func:`~secure3d.mapping.obstacle_boxes.closed_grid` followed by
:func:`~secure3d.mapping.boxes.merge_grid` walks a dense grid of one byte per cell: a scanned
building refined to 4 cm (1.5 M voxels) spans 30 M cells and the six closing passes, the
transposed copies and the greedy scan of every cell cost ~0.3-0.5 s of each plan call over it.
Here the grid holds one bit per cell, 64 cells of axis 0 to a word: a closing pass is a few word
operations per 64 cells, and the greedy merge jumps from set bit to set bit. The cells and the
boxes are the same, in the same order (tests compare them with the dense path on random grids,
across block boundaries):

- the closing is the same sequence of separable passes (a cube is the Minkowski sum of three
  3-cell segments: dilate along axes 0, 1, 2, ``radius`` times, then erode likewise; cells outside
  the grid count as empty, scipy's ``border_value=0``), then the union with the input;
- the merge cuts the grid at the same :data:`~secure3d.mapping.boxes.BLOCK_EDGE` boundaries and
  runs the same greedy rule in each block (from each free cell in axis-2, axis-1, axis-0 order,
  grow along axis 0, then axis 1 by whole rows, then axis 2 by whole slabs); a consumed cell is a
  cleared bit instead of a 2.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.mapping.boxes import BLOCK_EDGE
from secure3d.mapping.morton import _compact16, _ctz

__all__ = ["packed_closed_boxes"]

_ONE = np.uint64(1)
_ZERO = np.uint64(0)
_ALL = np.uint64(0xFFFFFFFFFFFFFFFF)
_SIX = np.uint64(6)
_63 = np.uint64(63)


@numba.njit(cache=True)
def _key_bounds(codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest and largest key per axis of Morton ``codes`` (n >= 1)."""
    lo = np.full(3, 1 << 30, np.int64)
    hi = np.full(3, -1, np.int64)
    for q in range(codes.shape[0]):
        c = codes[q]
        for a in range(3):
            k = _compact16(c >> a)
            lo[a] = min(lo[a], k)
            hi[a] = max(hi[a], k)
    return lo, hi


@numba.njit(cache=True)
def _pack(codes: np.ndarray, base: np.ndarray, d1: int, d2: int, nw: int) -> np.ndarray:
    """(d2, d1, nw) uint64 grid with the bit of cell key - ``base`` set for every code."""
    p = np.zeros((d2, d1, nw), np.uint64)
    for q in range(codes.shape[0]):
        c = codes[q]
        i = _compact16(c) - base[0]
        j = _compact16(c >> 1) - base[1]
        k = _compact16(c >> 2) - base[2]
        p[k, j, i >> 6] |= _ONE << np.uint64(i & 63)
    return p


@numba.njit(cache=True)
def _pass_bits(a: np.ndarray, b: np.ndarray, d0: int, erode: bool) -> None:
    """``b`` = ``a`` dilated (OR) or eroded (AND) by the 3-cell segment along axis 0 (the bits)."""
    d2, d1, nw = a.shape
    rem = d0 & 63
    tail = _ALL if rem == 0 else (_ONE << np.uint64(rem)) - _ONE
    for k in range(d2):
        for j in range(d1):
            for w in range(nw):
                v = a[k, j, w]
                left = v << _ONE  # cell x - 1 at bit x
                if w > 0:
                    left |= a[k, j, w - 1] >> _63
                right = v >> _ONE  # cell x + 1 at bit x
                if w + 1 < nw:
                    right |= a[k, j, w + 1] << _63
                out = (v & left & right) if erode else (v | left | right)
                if w == nw - 1:
                    out &= tail  # cells beyond the grid stay empty
                b[k, j, w] = out


@numba.njit(cache=True)
def _pass_rows(a: np.ndarray, b: np.ndarray, axis: int, erode: bool) -> None:
    """``b`` = ``a`` dilated or eroded by the 3-cell segment along axis 1 or 2 (whole words)."""
    d2, d1, nw = a.shape
    n = d1 if axis == 1 else d2
    for k in range(d2):
        for j in range(d1):
            t = j if axis == 1 else k
            for w in range(nw):
                v = a[k, j, w]
                for s in (-1, 1):
                    u = t + s
                    if u < 0 or u >= n:
                        if erode:  # a neighbour outside the grid is empty
                            v = _ZERO
                        continue
                    o = a[k, u, w] if axis == 1 else a[u, j, w]
                    v = (v & o) if erode else (v | o)
                b[k, j, w] = v


@numba.njit(cache=True)
def _closing(p: np.ndarray, d0: int, radius: int) -> np.ndarray:
    """The closing of packed grid ``p`` by the cube of half-width ``radius``, union ``p``."""
    a = p.copy()
    b = np.empty_like(p)
    for erode in (False, True):
        for _ in range(radius):
            _pass_bits(a, b, d0, erode)
            _pass_rows(b, a, 1, erode)
            _pass_rows(a, b, 2, erode)
            a, b = b, a
    for k in range(p.shape[0]):
        for j in range(p.shape[1]):
            for w in range(p.shape[2]):
                a[k, j, w] |= p[k, j, w]
    return a


@numba.njit(cache=True, inline="always")
def _mask(w: int, x0: int, x1: int) -> np.uint64:
    """Bits of word ``w`` that hold cells x0..x1 (inclusive)."""
    m = _ALL
    if w == x0 >> 6:
        m &= _ALL << np.uint64(x0 & 63)
    if w == x1 >> 6:
        m &= _ALL >> np.uint64(63 - (x1 & 63))
    return m


@numba.njit(cache=True)
def _row_full(g: np.ndarray, k: int, j: int, x0: int, x1: int) -> bool:
    """Whether cells x0..x1 of row (j, k) are all set."""
    for w in range(x0 >> 6, (x1 >> 6) + 1):
        m = _mask(w, x0, x1)
        if g[k, j, w] & m != m:
            return False
    return True


@numba.njit(cache=True)
def _next_set(g: np.ndarray, k: int, j: int, x: int, end: int) -> int:
    """First set cell of row (j, k) in [x, end), or -1."""
    if x >= end:
        return -1
    w = x >> 6
    v = g[k, j, w] & (_ALL << np.uint64(x & 63))
    while True:
        if v != _ZERO:
            p = (w << 6) + _ctz(v)
            return p if p < end else -1
        w += 1
        if w << 6 >= end:
            return -1
        v = g[k, j, w]


@numba.njit(cache=True)
def _grow(g: np.ndarray, z: int, y: int, x: int, a1: np.ndarray) -> tuple[int, int, int]:
    """The greedy box from free cell (x, y, z) within the block ending at ``a1`` (exclusive):
    its far corner (x1, y1, z1)."""
    x1 = x
    while x1 + 1 < a1[0] and (g[z, y, (x1 + 1) >> 6] >> np.uint64((x1 + 1) & 63)) & _ONE:
        x1 += 1
    y1 = y
    while y1 + 1 < a1[1] and _row_full(g, z, y1 + 1, x, x1):
        y1 += 1
    z1 = z
    while z1 + 1 < a1[2]:
        ok = True
        for yy in range(y, y1 + 1):
            if not _row_full(g, z1 + 1, yy, x, x1):
                ok = False
                break
        if not ok:
            break
        z1 += 1
    return x1, y1, z1


@numba.njit(cache=True)
def _greedy_block(g, a0, a1, out, m):
    """Greedy boxes of the block [a0, a1) of packed grid ``g`` (consumed: bits cleared), appended
    to ``out`` from row ``m`` (grid cells, inclusive); returns (out, new m)."""
    for z in range(a0[2], a1[2]):
        for y in range(a0[1], a1[1]):
            x = _next_set(g, z, y, a0[0], a1[0])
            while x >= 0:
                x1, y1, z1 = _grow(g, z, y, x, a1)
                for zz in range(z, z1 + 1):
                    for yy in range(y, y1 + 1):
                        for w in range(x >> 6, (x1 >> 6) + 1):
                            g[zz, yy, w] &= ~_mask(w, x, x1)
                if m == out.shape[0]:
                    bigger = np.empty((2 * m, 6), np.int64)
                    for r in range(m):  # element-wise: no shape-mismatch formatting compiled
                        for q in range(6):
                            bigger[r, q] = out[r, q]
                    out = bigger
                out[m, 0], out[m, 1], out[m, 2] = x, y, z
                out[m, 3], out[m, 4], out[m, 5] = x1, y1, z1
                m += 1
                x = _next_set(g, z, y, x1 + 1, a1[0])
    return out, m


@numba.njit(cache=True)
def _merge_packed(g: np.ndarray, dims: np.ndarray, origin: np.ndarray, edge: int) -> np.ndarray:
    """Greedy boxes of packed grid ``g`` block by block (blocks of ``edge`` cells aligned on
    multiples of ``edge`` in the cells' absolute coordinates ``origin + index``), in
    :func:`~secure3d.mapping.boxes.merge_grid`'s order; consumes ``g``. (m, 6) grid cells."""
    end = origin + dims
    first = origin // edge
    last = (end - 1) // edge
    out = np.empty((1024, 6), np.int64)
    m = 0
    a0 = np.empty(3, np.int64)
    a1 = np.empty(3, np.int64)
    for bz in range(first[2], last[2] + 1):
        for by in range(first[1], last[1] + 1):
            for bx in range(first[0], last[0] + 1):
                b = (bx, by, bz)
                for a in range(3):
                    a0[a] = max(b[a] * edge, origin[a]) - origin[a]
                    a1[a] = min((b[a] + 1) * edge, end[a]) - origin[a]
                out, m = _greedy_block(g, a0, a1, out, m)
    return out[:m]


def packed_closed_boxes(
    codes: NDArray[np.int64], radius: int
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """``merge_grid(*closed_grid(morton_decode(codes), radius))``: the greedy boxes (inclusive key
    bounds) of the closing of the voxels ``codes`` by the cube of half-width ``radius``, the same
    boxes in the same order, without a keys array or a dense grid.

    Parameters
    ----------
    codes : (n,) int64
        Unique Morton codes of OctoMap keys, n >= 1.
    radius : int >= 1

    Returns
    -------
    lo, hi : (m, 3) int64
    """
    codes = np.ascontiguousarray(codes, dtype=np.int64).ravel()
    pad = int(radius) + 1
    kmin, kmax = _key_bounds(codes)
    base = kmin - pad
    dims = kmax - base + pad + 1
    nw = (int(dims[0]) + 63) >> 6
    g = _closing(_pack(codes, base, int(dims[1]), int(dims[2]), nw), int(dims[0]), int(radius))
    boxes = _merge_packed(g, dims, base, BLOCK_EDGE)
    return boxes[:, :3] + base, boxes[:, 3:] + base
