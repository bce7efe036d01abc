"""Morphological closing of a sparse cell set by a cube, visiting only the cells it can change.

:func:`~secure3d.mapping.obstacle_boxes.binary_closing_cube` works on the whole dense grid around
the map: every pass reads and writes every cell, so a map of 10^6 voxels spread over an
80 m x 80 m floor (133 M cells at 5 cm) costs about 1 s, although the closing can only set cells
within the cube's radius of an occupied voxel. The kernel here computes the same cells (a test
compares them on random grids) by the same separable passes (a cube is the Minkowski sum of three
segments: dilate along x, y, z, then erode along x, y, z; cells outside the grid count as empty,
scipy's ``border_value=0``), but only on the tiles of 8**3 cells within the radius of a voxel.
Every other cell of the dilation, and so of the closing, is empty; tiles are allocated only there,
so a sparse map never touches (nor zeroes) the pages of its whole bounding grid. Cost:
O(tiles * 512 * (2r+1)) per pass instead of O(X * Y * Z).
"""

from __future__ import annotations

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import GeometryError

__all__ = ["sparse_closing"]


#: Tiles of 8**3 cells hold the working sets: only tiles within the radius of a voxel are ever
#: allocated, so a sparse map never touches (nor zeroes) the pages of its whole bounding grid.
TILE_BITS = 3
TILE = 1 << TILE_BITS


@numba.njit(cache=True)
def _allocate(tiles: np.ndarray, idx: np.ndarray, r: int, dims: np.ndarray) -> np.ndarray:
    """Give every tile within ``r`` cells (per axis) of a cell a slot in ``tiles`` (-1: none);
    returns the (n_slots, 3) tile coordinates of the slots."""
    coords = np.empty((64, 3), np.int64)
    n = 0
    lo = np.empty(3, np.int64)  # scratch, reused for every cell
    hi = np.empty(3, np.int64)
    for q in range(idx.shape[0]):
        for a in range(3):
            lo[a] = max(idx[q, a] - r, 0) >> TILE_BITS
            hi[a] = min(idx[q, a] + r, dims[a] - 1) >> TILE_BITS
        for tx in range(lo[0], hi[0] + 1):
            for ty in range(lo[1], hi[1] + 1):
                for tz in range(lo[2], hi[2] + 1):
                    if tiles[tx, ty, tz] >= 0:
                        continue
                    tiles[tx, ty, tz] = n
                    if n == coords.shape[0]:
                        bigger = np.empty((2 * n, 3), np.int64)
                        for i in range(n):  # element-wise: no shape-mismatch formatting compiled
                            for a in range(3):
                                bigger[i, a] = coords[i, a]
                        coords = bigger
                    coords[n, 0], coords[n, 1], coords[n, 2] = tx, ty, tz
                    n += 1
    return coords[:n]


@numba.njit(cache=True)
def _get(src: np.ndarray, s: int, axis: int, t: int, p: int, q: int) -> bool:
    """Cell ``t`` along ``axis`` of line (p, q) of tile slot ``s`` (False for slot -1)."""
    if s < 0:
        return False
    if axis == 0:
        return src[s, t, p, q]
    if axis == 1:
        return src[s, p, t, q]
    return src[s, p, q, t]


@numba.njit(cache=True)
def _set(dst: np.ndarray, s: int, axis: int, t: int, p: int, q: int, v: bool) -> None:
    if axis == 0:
        dst[s, t, p, q] = v
    elif axis == 1:
        dst[s, p, t, q] = v
    else:
        dst[s, p, q, t] = v


@numba.njit(cache=True)
def _neighbour(tiles: np.ndarray, c: np.ndarray, axis: int, step: int) -> int:
    """Slot of the tile ``step`` tiles along ``axis`` from tile ``c`` (-1: none)."""
    x, y, z = c[0], c[1], c[2]
    if axis == 0:
        x += step
    elif axis == 1:
        y += step
    else:
        z += step
    if x < 0 or y < 0 or z < 0 or x >= tiles.shape[0] or y >= tiles.shape[1]:
        return -1
    if z >= tiles.shape[2]:
        return -1
    return tiles[x, y, z]


@numba.njit(cache=True)
def _pass(src, dst, tiles, coords, dims, axis: int, r: int, erode: bool) -> None:
    """``dst`` = ``src`` dilated (OR) or eroded (AND) by the segment of half-width ``r`` (<= 8)
    along ``axis``, line by line through each tile with ``r`` cells of the tiles either side."""
    line = np.zeros(TILE + 2 * r, np.bool_)
    for s in range(coords.shape[0]):
        before = _neighbour(tiles, coords[s], axis, -1)
        after = _neighbour(tiles, coords[s], axis, 1)
        base = coords[s, axis] * TILE  # grid coordinate of the tile's first cell along axis
        for p in range(TILE):
            for q in range(TILE):
                for t in range(r):
                    line[t] = _get(src, before, axis, TILE - r + t, p, q)
                    line[TILE + r + t] = _get(src, after, axis, t, p, q)
                for t in range(TILE):
                    line[r + t] = src[s, t, p, q] if axis == 0 else _get(src, s, axis, t, p, q)
                for t in range(TILE):
                    v = erode
                    for d in range(2 * r + 1):
                        if line[t + d] != erode:  # OR met a set cell / AND met an empty one
                            v = not erode
                            break
                    # cells beyond the grid's end (in its last tiles) stay empty
                    _set(dst, s, axis, t, p, q, v and base + t < dims[axis])


@numba.njit(cache=True)
def _closing_tiles(idx: np.ndarray, dims: np.ndarray, r: int):
    """The closing as tiles: (slots (n, 8, 8, 8) bool, tile coordinates (n, 3))."""
    shape = (dims + TILE - 1) >> TILE_BITS
    tiles = np.full((shape[0], shape[1], shape[2]), -1, np.int64)
    coords = _allocate(tiles, idx, r, dims)
    a = np.zeros((coords.shape[0], TILE, TILE, TILE), np.bool_)
    b = np.zeros_like(a)
    m = TILE - 1
    for q in range(idx.shape[0]):
        x, y, z = idx[q, 0], idx[q, 1], idx[q, 2]
        a[tiles[x >> TILE_BITS, y >> TILE_BITS, z >> TILE_BITS], x & m, y & m, z & m] = True
    for erode in (False, True):
        for axis in range(3):
            _pass(a, b, tiles, coords, dims, axis, r, erode)
            a, b = b, a
    return a, coords


def sparse_closing(idx: np.ndarray, shape: tuple[int, int, int], radius: int) -> np.ndarray:
    """``binary_closing_cube(grid, radius) | grid`` for the grid of ``shape`` whose set cells are
    ``idx``, computed on the tiles near them only.

    Parameters
    ----------
    idx : (n, 3) int
        Unique cell indices, each within ``shape``.
    shape : (X, Y, Z)
    radius : closing radius (cells), >= 1: a cube of edge ``2 * radius + 1``.

    Returns
    -------
    (X, Y, Z) bool
    """
    dims = np.asarray(shape, dtype=np.int64)
    idx = np.ascontiguousarray(idx, dtype=np.int64).reshape(-1, 3)
    if dims.shape != (3,) or np.any(dims < 1):
        raise GeometryError(f"sparse_closing: shape must be 3 positive sizes, got {shape}")
    if not 1 <= int(radius) <= TILE:
        raise GeometryError(f"sparse_closing: radius must lie in [1, {TILE}], got {radius}")
    if len(idx) and (np.any(idx < 0) or np.any(idx >= dims)):
        raise GeometryError("sparse_closing: cell indices must lie within the shape")
    out = np.zeros(tuple(int(v) for v in dims), dtype=bool)
    if len(idx) == 0:
        return out
    slots, coords = _closing_tiles(idx, dims, int(radius))
    t, i, j, k = np.nonzero(slots)
    cells = coords[t] * TILE + np.stack([i, j, k], axis=1)
    out[cells[:, 0], cells[:, 1], cells[:, 2]] = True
    out[idx[:, 0], idx[:, 1], idx[:, 2]] = True  # the closing contains its input
    return out
