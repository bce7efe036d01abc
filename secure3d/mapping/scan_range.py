"""Scans whose free space counts only near the sensor (``free_range``).

A ray that meets no obstacle clears every voxel it crosses, however far. But a camera's rays fan
out: beyond its *observed range* (:func:`secure3d.mapping.observability.observed_range`) they pass
either side of a thin obstacle without touching it, and the voxels around it are cleared as
readily as empty ones. A map that should hold only free space the sensor would have noticed an
obstacle in (the start region of a replan in flight, :func:`secure3d.simulation.loop.observed_box`)
clears along each ray only within ``free_range`` of the sensor; hits count out to ``max_range``
as before.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import GeometryError
from secure3d.mapping.morton import (
    _sorted_codes_to_tiles,
    box_keys,
    morton_encode,
    unique_sorted,
)
from secure3d.mapping.raycast import _clipped_ends, check_origin, check_points
from secure3d.mapping.scan import ScanTiles, _discretize_kernel, scan_tiles
from secure3d.validation import is_real

__all__ = ["scan_tiles_free_range"]


def scan_tiles_free_range(
    points: ArrayLike,
    origin: ArrayLike,
    resolution: float,
    max_range: float | None,
    free_range: float,
    discretize: bool = False,
    clear_range: float | None = None,
    box: ArrayLike | None = None,
    free_axis: ArrayLike | None = None,
) -> ScanTiles:
    """:func:`~secure3d.mapping.scan.scan_tiles` with each ray clearing space only within
    ``free_range`` (m) of the sensor: the Euclidean distance from ``origin``, or with
    ``free_axis`` (a unit vector, a camera's optical axis) the depth along it (a plane).

    The hits are the same (out to ``max_range``). Each ray clears the voxels it crosses up to the
    shorter of its own clearing length (to its hit, or ``clear_range`` for a beam beyond
    ``max_range``) and its free range; the voxel where it stops is not cleared (as OctoMap leaves
    the end voxel of a beam it clips) and neither is any hit (occupied wins within a scan). So every
    cleared voxel lies within ``free_range`` plus a voxel diagonal of the sensor (in distance, or
    in depth), and is one the scan without ``free_range`` clears (but where a ray runs exactly
    along a voxel's edge: there the walk's choice of voxel may flip with the last bit of its
    shortened end). A ray whose end lies outside the key range is dropped whole, as without it.
    Returns the statistics of the scan without ``free_range``; other parameters as
    ``scan_tiles``. Raises :class:`GeometryError` for a ``free_range`` that is not a number >= 0
    or a ``free_axis`` that is not a unit 3-vector."""
    fr, axis = _check_free(free_range, free_axis)
    unlimited = max_range is None or not math.isfinite(max_range)
    mr = -1.0 if unlimited else float(max_range)
    cr = mr if clear_range is None else float(clear_range)
    if math.isinf(fr) or (axis is None and not unlimited and fr >= mr):
        return scan_tiles(points, origin, resolution, max_range, discretize, clear_range, box)
    p = np.ascontiguousarray(check_points(points))
    o = check_origin(origin, resolution).astype(np.float64)
    if discretize:
        ends, nonfinite, outside = _discretize_kernel(p, float(resolution))
    else:
        ends = p
    _, keys, status, _, _ = _clipped_ends(ends, o, float(resolution), mr, cr)
    counts = np.bincount(status, minlength=4)
    cut = _cut_ends(ends, o, status, cr, fr, axis)
    near = scan_tiles(cut, o, resolution, None, False, None, box)
    hits = _hit_codes(keys[status == 0], box, resolution)
    blocks, masks = _tiles_less(near.blocks, near.masks, hits)
    used = int(counts[0] + counts[1])
    if discretize:
        stats = (p.shape[0] - nonfinite - outside, int(nonfinite), int(outside))
    else:
        stats = (used, int(counts[2]), int(counts[3]))
    return ScanTiles(blocks, masks, hits, *stats, int(counts[1]), used)


def _check_free(free_range: float, free_axis: ArrayLike | None) -> tuple[float, np.ndarray | None]:
    """(free range, unit axis or None), validated."""
    if not is_real(free_range, numpy=True) or not float(free_range) >= 0.0:  # NaN too
        raise GeometryError(f"free_range: expected a number >= 0, got {free_range!r}")
    if free_axis is None:
        return float(free_range), None
    try:
        axis = np.asarray(free_axis, dtype=np.float64)
    except (TypeError, ValueError):
        axis = np.full(3, np.nan)
    if axis.shape != (3,) or not abs(float(np.linalg.norm(axis)) - 1.0) <= 1e-6:
        raise GeometryError(f"free_axis: expected a unit 3-vector, got {free_axis!r}")
    return float(free_range), axis


def _cut_ends(
    ends: np.ndarray,
    o: np.ndarray,
    status: np.ndarray,
    clear: float,
    free: float,
    axis: np.ndarray | None,
) -> np.ndarray:
    """(n, 3): each ray's end moved back to where it stops clearing space (its hit, or ``clear``
    for a clipped beam, or where it reaches ``free`` (distance, or depth along ``axis``) if
    sooner); NaN for rays the scan drops. A ray that does not go forwards along ``axis`` clears
    nothing."""
    along = np.zeros(3) if axis is None else axis
    return _cut_kernel(
        np.asarray(ends, np.float64), o, status, clear, free, along, axis is not None
    )


@numba.njit(cache=True)
def _cut_kernel(
    ends: np.ndarray,
    o: np.ndarray,
    status: np.ndarray,
    clear: float,
    free: float,
    axis: np.ndarray,
    use_axis: bool,
) -> np.ndarray:
    """:func:`_cut_ends` over the rays, one loop."""
    n = ends.shape[0]
    out = np.empty((n, 3), np.float64)
    for i in range(n):
        if status[i] >= 2:
            out[i, :] = np.nan
            continue
        dx = ends[i, 0] - o[0]
        dy = ends[i, 1] - o[1]
        dz = ends[i, 2] - o[2]
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        own = clear if status[i] == 1 else length
        limit = free
        if use_axis:
            per_m = (dx * axis[0] + dy * axis[1] + dz * axis[2]) / length if length > 0 else 0.0
            limit = free / per_m if per_m > 0 else 0.0
        cut = min(own, limit)
        if length > 0 and cut < length:
            s = cut / length
            out[i, 0] = o[0] + dx * s
            out[i, 1] = o[1] + dy * s
            out[i, 2] = o[2] + dz * s
        else:
            out[i, :] = ends[i, :]
    return out


def _hit_codes(keys: np.ndarray, box: ArrayLike | None, resolution: float) -> np.ndarray:
    """Morton codes (k,) of the end keys ``keys`` (k, 3) that meet ``box``, each once, ascending."""
    if box is not None:
        keep = box_keys(box, resolution)
        keys = keys[np.all((keys >= keep[0]) & (keys <= keep[1]), axis=1)]
    return unique_sorted(morton_encode(keys)) if len(keys) else np.empty(0, np.int64)


def _tiles_less(
    blocks: np.ndarray, masks: np.ndarray, codes: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Tiles (``blocks`` (m,), ``masks`` (m,)) less the voxels ``codes`` (k,, ascending): (blocks,
    masks), tiles left empty dropped."""
    if not len(codes) or not len(blocks):
        return blocks, masks
    hb, hm = _sorted_codes_to_tiles(codes)  # ascending blocks
    at = np.minimum(np.searchsorted(hb, blocks), len(hb) - 1)
    match = hb[at] == blocks
    masks = masks.copy()
    masks[match] &= ~hm[at[match]]
    keep = masks != 0
    return blocks[keep], masks[keep]
