"""Closed boundary mesh of a voxel set: one quad (two triangles) per face between a voxel in the set
and one outside it.

Vertices are the integer voxel corners, shared by every face that touches them, and every quad is
wound counter-clockwise seen from outside (normal pointing out of the set). Hence every directed
edge is matched by its reverse: the surface is closed and consistently oriented, its divergence-
theorem volume is exactly the voxel volume, and ray parity tests work. Where two voxels of the set
touch only along an edge, that edge is shared by four faces (closed, but not 2-manifold there), as
for any exact voxel boundary.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from secure3d.errors import GeometryError

# Corner offsets of the face of a unit cube with outward normal along +/- each axis, ordered
# counter-clockwise seen from outside.
_FACE_CORNERS = {
    (0, 1): ((1, 0, 0), (1, 1, 0), (1, 1, 1), (1, 0, 1)),
    (0, -1): ((0, 0, 0), (0, 0, 1), (0, 1, 1), (0, 1, 0)),
    (1, 1): ((0, 1, 0), (0, 1, 1), (1, 1, 1), (1, 1, 0)),
    (1, -1): ((0, 0, 0), (1, 0, 0), (1, 0, 1), (0, 0, 1)),
    (2, 1): ((0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)),
    (2, -1): ((0, 0, 0), (0, 1, 0), (1, 1, 0), (1, 0, 0)),
}

# Cells are packed with 21 bits per axis after a +1 shift so that neighbours of key 0 or 65535
# still pack without colliding.
_BITS = 21


def _pack(cells: NDArray[np.int64]) -> NDArray[np.int64]:
    c = cells + 1
    return c[:, 0] | (c[:, 1] << _BITS) | (c[:, 2] << (2 * _BITS))


def boundary_mesh(cells: NDArray[np.integer]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Boundary surface of a set of unit cells.

    Parameters
    ----------
    cells : (n, 3) int
        Unique integer cell indices; cell ``c`` is the unit cube ``[c, c + 1]``.

    Returns
    -------
    corners : (v, 3) int64
        Integer corner positions (cell units), each once.
    faces : (f, 3) int64
        Triangles indexing ``corners``, counter-clockwise seen from outside.
    """
    cells = np.unique(np.asarray(cells, dtype=np.int64).reshape(-1, 3), axis=0)
    if cells.shape[0] == 0:
        return np.empty((0, 3), np.int64), np.empty((0, 3), np.int64)
    packed = np.sort(_pack(cells))
    quads = []
    for (axis, sign), corners in _FACE_CORNERS.items():
        step = np.zeros(3, np.int64)
        step[axis] = sign
        nb = _pack(cells + step)
        pos = np.searchsorted(packed, nb)
        present = packed[np.minimum(pos, packed.size - 1)] == nb
        exposed = cells[~present]
        quads.append(exposed[:, None, :] + np.asarray(corners, np.int64)[None])
    quad_corners = np.concatenate(quads)  # (q, 4, 3)
    corner_ids = _pack(quad_corners.reshape(-1, 3) - 1)
    uniq, inverse = np.unique(corner_ids, return_inverse=True)
    corners = np.empty((uniq.size, 3), np.int64)
    corners[inverse] = quad_corners.reshape(-1, 3)
    q = inverse.reshape(-1, 4)
    faces = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    return corners, faces


#: Largest bounding grid (cells) :func:`surface_mask` allocates; a larger set counts as all surface.
MAX_SURFACE_GRID = 1 << 26


def surface_mask(cells: NDArray[np.integer]) -> NDArray[np.bool_]:
    """Which of the integer ``cells`` (n, 3) have a face neighbour outside the set: the voxels a
    solid rendering of the set can show (the others are enclosed by them).

    Computed on a dense grid over the set's bounding box (a few ms for 10^5 cells); all True when
    that grid would exceed :data:`MAX_SURFACE_GRID` cells.
    """
    arr = np.asarray(cells)
    if (
        arr.ndim != 2
        or arr.shape[1] != 3
        or not (arr.size == 0 or np.issubdtype(arr.dtype, np.integer))
    ):
        raise GeometryError(
            f"cells: expected an (n, 3) array of integers, got shape {arr.shape} of {arr.dtype}"
        )
    cols = np.ascontiguousarray(arr.astype(np.int64).T)
    if not cols.shape[1]:
        return np.zeros(0, dtype=bool)
    lo = cols.min(axis=1) - 1  # a free layer around the set: every neighbour is in the grid
    dims = tuple(int(d) for d in cols.max(axis=1) - lo + 2)
    if dims[0] * dims[1] * dims[2] > MAX_SURFACE_GRID:
        return np.ones(cols.shape[1], dtype=bool)
    flat = np.ravel_multi_index(tuple(cols - lo[:, None]), dims)
    grid = np.zeros(dims, dtype=bool)
    grid.ravel()[flat] = True
    inner = np.zeros(dims, dtype=bool)
    mid = (slice(1, -1),) * 3
    inner[mid] = grid[mid]
    for axis in range(3):
        for step in (slice(2, None), slice(None, -2)):
            shifted = list(mid)
            shifted[axis] = step
            inner[mid] &= grid[tuple(shifted)]
    return ~inner.ravel()[flat]
