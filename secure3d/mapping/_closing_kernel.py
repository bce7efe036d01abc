"""Morphological closing of a sparse cell set by a cube, visiting only the cells it can change.

:func:`~secure3d.mapping.obstacle_boxes.binary_closing_cube` works on the whole dense grid around
the map: every pass reads and writes every cell, so a map of 10^6 voxels spread over an
80 m x 80 m floor (133 M cells at 5 cm) costs about 1 s, although the closing can only set cells
within the cube's radius of an occupied voxel. The kernel here computes the same cells (a test
compares them on random grids) by the same separable passes (a cube is the Minkowski sum of three
segments), but each pass walks the list of cells set by the previous one:

- dilation along an axis: every listed cell sets its segment of neighbours (each new cell listed
  once);
- erosion along an axis: a listed cell survives if its whole segment is set (cells outside the
  grid count as empty, scipy's ``border_value=0``).

Cells are flat indices into a C-ordered grid of shape (X, Y, Z). Cost: O(|dilated set| * (2r+1))
per pass instead of O(X * Y * Z).
"""

from __future__ import annotations

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)

__all__ = ["sparse_closing"]


@numba.njit(cache=True)
def _grow(buf: np.ndarray, m: int) -> np.ndarray:
    """``buf`` with twice the room, its first ``m`` entries kept (element by element: a slice
    assignment would make numba compile its shape-mismatch message formatting)."""
    bigger = np.empty(2 * buf.shape[0] + 16, np.int64)
    for i in range(m):
        bigger[i] = buf[i]
    return bigger


@numba.njit(cache=True)
def _coord(flat: int, axis: int, dims: np.ndarray) -> int:
    """Coordinate along ``axis`` of the flat index of a C-ordered (X, Y, Z) grid."""
    if axis == 0:
        return flat // (dims[1] * dims[2])
    if axis == 1:
        return (flat // dims[2]) % dims[1]
    return flat % dims[2]


@numba.njit(cache=True)
def _dilate(cells: np.ndarray, n: int, dst: np.ndarray, axis: int, r: int, dims: np.ndarray):
    """Set in ``dst`` (flat, all False on entry) every cell within ``r`` along ``axis`` of the
    first ``n`` of ``cells``; returns the list of cells set and its length."""
    stride = dims[2] * dims[1] if axis == 0 else (dims[2] if axis == 1 else 1)
    out = np.empty(3 * n + 16, np.int64)
    m = 0
    for q in range(n):
        c = cells[q]
        x = _coord(c, axis, dims)
        for d in range(-r, r + 1):
            if x + d < 0 or x + d >= dims[axis]:
                continue
            e = c + d * stride
            if not dst[e]:
                dst[e] = True
                if m == out.shape[0]:
                    out = _grow(out, m)
                out[m] = e
                m += 1
    return out, m


@numba.njit(cache=True)
def _erode(
    cells: np.ndarray, n: int, src: np.ndarray, dst: np.ndarray, axis: int, r: int, dims: np.ndarray
):
    """Set in ``dst`` (flat, all False on entry) each of the first ``n`` of ``cells`` (the cells
    set in ``src``) whose whole segment of half-width ``r`` along ``axis`` is set in ``src``;
    returns the survivors and their number."""
    stride = dims[2] * dims[1] if axis == 0 else (dims[2] if axis == 1 else 1)
    out = np.empty(n + 16, np.int64)
    m = 0
    for q in range(n):
        c = cells[q]
        x = _coord(c, axis, dims)
        keep = True
        for d in range(-r, r + 1):
            if x + d < 0 or x + d >= dims[axis] or not src[c + d * stride]:
                keep = False
                break
        if keep:
            dst[c] = True
            out[m] = c
            m += 1
    return out, m


@numba.njit(cache=True)
def _clear(grid: np.ndarray, cells: np.ndarray, n: int) -> None:
    for q in range(n):
        grid[cells[q]] = False


@numba.njit(cache=True)
def _closing_flat(flat: np.ndarray, dims: np.ndarray, r: int) -> np.ndarray:
    size = dims[0] * dims[1] * dims[2]
    a = np.zeros(size, np.bool_)
    b = np.zeros(size, np.bool_)
    l1, n1 = _dilate(flat, flat.shape[0], a, 0, r, dims)
    l2, n2 = _dilate(l1, n1, b, 1, r, dims)
    _clear(a, l1, n1)
    l3, n3 = _dilate(l2, n2, a, 2, r, dims)  # a: the dilation
    _clear(b, l2, n2)
    l4, n4 = _erode(l3, n3, a, b, 0, r, dims)
    _clear(a, l3, n3)
    l5, n5 = _erode(l4, n4, b, a, 1, r, dims)
    _clear(b, l4, n4)
    _erode(l5, n5, a, b, 2, r, dims)  # b: the closing
    for q in range(flat.shape[0]):
        b[flat[q]] = True
    return b


def sparse_closing(idx: np.ndarray, shape: tuple[int, int, int], radius: int) -> np.ndarray:
    """``binary_closing_cube(grid, radius) | grid`` for the grid of ``shape`` whose set cells are
    ``idx``, computed without passing over the empty space.

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
    idx = np.asarray(idx, dtype=np.int64).reshape(-1, 3)
    flat = (idx[:, 0] * dims[1] + idx[:, 1]) * dims[2] + idx[:, 2]
    return _closing_flat(np.ascontiguousarray(flat), dims, int(radius)).reshape(tuple(dims))
