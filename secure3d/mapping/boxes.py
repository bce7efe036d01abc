"""Planner views of a voxel set: merged axis-aligned boxes and the boxes near a corridor.

The planner's obstacle constraints are convex polytopes (DESIGN.md section 4, "Known obstacles"),
one dual multiplier vector per obstacle and node, so the fewer boxes the better. Voxels are merged
greedily on a dense grid (in blocks of at most 256**3 cells): from each unused voxel in x-fastest
order, grow the box along x as far as possible, then along y while whole rows are free to take,
then along z while whole slabs are. Every voxel ends up in exactly one box and boxes cover no other
cell, so the union is exact. When a box budget is given and exceeded, the set is coarsened by 2 per
axis (a coarse cell is an obstacle if any of its voxels is) until it fits: a superset, so merging
never drops an obstacle.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import GeometryError

#: Block edge (cells) of the dense grids the greedy merge works on (256**3 bytes = 16 MB).
BLOCK_EDGE = 256


@numba.njit(cache=True)
def _greedy_boxes(grid: np.ndarray) -> np.ndarray:
    """Greedy box cover of the cells equal to 1 of ``grid`` (indexed [z, y, x]); consumes it.

    Returns ``(m, 6) int64`` rows ``x0, y0, z0, x1, y1, z1`` (inclusive).
    """
    nz, ny, nx = grid.shape
    out = np.empty((1024, 6), np.int64)
    m = 0
    for z in range(nz):
        for y in range(ny):
            for x in range(nx):
                if grid[z, y, x] != 1:
                    continue
                x1 = x
                while x1 + 1 < nx and grid[z, y, x1 + 1] == 1:
                    x1 += 1
                y1 = y
                while y1 + 1 < ny:
                    ok = True
                    for xx in range(x, x1 + 1):
                        if grid[z, y1 + 1, xx] != 1:
                            ok = False
                            break
                    if not ok:
                        break
                    y1 += 1
                z1 = z
                while z1 + 1 < nz:
                    ok = True
                    for yy in range(y, y1 + 1):
                        for xx in range(x, x1 + 1):
                            if grid[z1 + 1, yy, xx] != 1:
                                ok = False
                                break
                        if not ok:
                            break
                    if not ok:
                        break
                    z1 += 1
                grid[z : z1 + 1, y : y1 + 1, x : x1 + 1] = 2
                if m == out.shape[0]:
                    bigger = np.empty((2 * m, 6), np.int64)
                    # element by element: an array slice assignment makes numba compile its
                    # shape-mismatch message formatting (~3 s of first-run compilation)
                    for r in range(m):
                        for q in range(6):
                            bigger[r, q] = out[r, q]
                    out = bigger
                out[m, 0] = x
                out[m, 1] = y
                out[m, 2] = z
                out[m, 3] = x1
                out[m, 4] = y1
                out[m, 5] = z1
                m += 1
    return out[:m]


def merge_cells(cells: NDArray[np.integer]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Cover integer cells exactly with few axis-aligned boxes (greedy, see module docstring).

    Parameters
    ----------
    cells : (n, 3) int
        Unique cell indices (e.g. OctoMap keys).

    Returns
    -------
    lo, hi : (m, 3) int64
        Inclusive cell bounds of each box; boxes are disjoint and their union is ``cells``.
    """
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    if cells.shape[0] == 0:
        return np.empty((0, 3), np.int64), np.empty((0, 3), np.int64)
    block = cells // BLOCK_EDGE
    order = np.lexsort((block[:, 0], block[:, 1], block[:, 2]))
    cells, block = cells[order], block[order]
    starts = np.flatnonzero(np.r_[True, np.any(block[1:] != block[:-1], axis=1)])
    ends = np.r_[starts[1:], cells.shape[0]]
    los, his = [], []
    # One dense grid per non-empty block: a handful of blocks even for large maps.
    for a, b in zip(starts, ends, strict=True):
        local = cells[a:b]
        origin = local.min(axis=0)
        rel = local - origin
        dims = rel.max(axis=0) + 1
        grid = np.zeros((dims[2], dims[1], dims[0]), np.uint8)
        grid[rel[:, 2], rel[:, 1], rel[:, 0]] = 1
        boxes = _greedy_boxes(grid)
        los.append(boxes[:, :3] + origin)
        his.append(boxes[:, 3:] + origin)
    return np.concatenate(los), np.concatenate(his)


def merge_grid(
    grid: NDArray[np.bool_], origin: NDArray[np.integer]
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """:func:`merge_cells` of the cells set in a dense grid, read off the grid itself.

    Parameters
    ----------
    grid : (X, Y, Z) bool
        Cell ``origin + (i, j, k)`` is in the set where ``grid[i, j, k]``.
    origin : (3,) int

    Returns
    -------
    lo, hi : (m, 3) int64
        The same boxes in the same order as ``merge_cells(np.argwhere(grid) + origin)``: the grid
        is cut at the same block boundaries and each block merged in the same cell order, without
        listing, sorting and re-gridding the cells.
    """
    origin = np.asarray(origin)
    if origin.shape != (3,) or not np.issubdtype(origin.dtype, np.integer):
        raise GeometryError(f"merge_grid: origin must be 3 integers, got {origin!r}")
    origin = origin.astype(np.int64)
    grid = np.asarray(grid, dtype=bool)
    if grid.ndim != 3:
        raise GeometryError(f"merge_grid: expected a 3D grid, got shape {grid.shape}")
    end = origin + np.array(grid.shape)
    first, last = origin // BLOCK_EDGE, (end - 1) // BLOCK_EDGE
    los, his = [], []
    for bz in range(first[2], last[2] + 1):
        for by in range(first[1], last[1] + 1):
            for bx in range(first[0], last[0] + 1):
                b = np.array([bx, by, bz])
                a0 = np.maximum(b * BLOCK_EDGE, origin) - origin
                a1 = np.minimum((b + 1) * BLOCK_EDGE, end) - origin
                block = grid[a0[0] : a1[0], a0[1] : a1[1], a0[2] : a1[2]]
                if not block.any():
                    continue
                zyx = np.ascontiguousarray(block.transpose(2, 1, 0)).view(np.uint8)
                boxes = _greedy_boxes(zyx.copy())
                los.append(boxes[:, :3] + origin + a0)
                his.append(boxes[:, 3:] + origin + a0)
    if not los:
        return np.empty((0, 3), np.int64), np.empty((0, 3), np.int64)
    return np.concatenate(los), np.concatenate(his)


def merge_cells_budget(
    cells: NDArray[np.integer], max_boxes: int | None = None
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """:func:`merge_cells` with an optional box budget, met by conservative coarsening.

    Parameters
    ----------
    cells : (n, 3) int
    max_boxes : int or None
        If the exact cover needs more boxes, cells are coarsened by 2, 4, ... per axis (a coarse
        cell is taken if any of its cells is) until the cover fits. The result then covers a
        superset of ``cells``, never less.

    Returns
    -------
    lo, hi : (m, 3) int64
        Inclusive bounds in the original cell units.
    """
    if max_boxes is not None and max_boxes < 1:
        raise GeometryError(f"max_boxes must be >= 1, got {max_boxes}")
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    lo, hi = merge_cells(cells)
    shift = 0
    while max_boxes is not None and lo.shape[0] > max_boxes:
        shift += 1
        coarse = np.unique(cells >> shift, axis=0)
        lo, hi = merge_cells(coarse)
        lo, hi = lo << shift, ((hi + 1) << shift) - 1
        if coarse.shape[0] == 1:
            break
    return lo, hi


def box_point_distance(
    lo: NDArray[np.floating], hi: NDArray[np.floating], points: NDArray[np.floating]
) -> NDArray[np.float64]:
    """Euclidean distance from every point to every box (0 inside).

    Parameters
    ----------
    lo, hi : (m, 3) float
    points : (k, 3) float

    Returns
    -------
    (m, k) float64
    """
    gap = np.maximum(lo[:, None, :] - points[None], 0.0) + np.maximum(
        points[None] - hi[:, None, :], 0.0
    )
    return np.sqrt(np.einsum("mkd,mkd->mk", gap, gap))


def boxes_near_points(
    lo: NDArray[np.floating],
    hi: NDArray[np.floating],
    points: NDArray[np.floating],
    radius: float,
) -> NDArray[np.bool_]:
    """Which boxes come within ``radius`` of at least one point.

    A KD-tree on the points discards boxes whose centre is farther than ``radius`` plus the box's
    half-diagonal from every point; the rest are checked exactly, in chunks of bounded memory.

    Parameters
    ----------
    lo, hi : (m, 3) float
    points : (k, 3) float
    radius : float

    Returns
    -------
    (m,) bool
    """
    m = lo.shape[0]
    near = np.zeros(m, bool)
    if m == 0 or points.shape[0] == 0:
        return near
    centre = 0.5 * (lo + hi)
    half_diag = 0.5 * np.linalg.norm(hi - lo, axis=1)
    tree = cKDTree(points)
    bound = radius + half_diag
    dist, _ = tree.query(centre, k=1, distance_upper_bound=float(bound.max()) + 1e-9)
    cand = np.flatnonzero(dist <= bound + 1e-9)
    chunk = max(1, 4_000_000 // points.shape[0])
    for a in range(0, cand.size, chunk):
        idx = cand[a : a + chunk]
        near[idx] = box_point_distance(lo[idx], hi[idx], points).min(axis=1) <= radius
    return near
