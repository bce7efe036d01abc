"""Ray casting as OctoMap does it: a scan's clipped ray ends and the 3D DDA of one ray.

A ray's free keys come from OctoMap's ``computeRayKeys`` (Amanatides & Woo DDA): the origin voxel
is included, the end voxel excluded, with the same float/double mix (so ties break the same way).
A beam longer than ``max_range`` only clears space up to ``max_range`` along its direction and
marks nothing occupied. The batched traversal of a whole scan is :mod:`secure3d.mapping.scan`'s.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import GeometryError
from secure3d.mapping.morton import TREE_MAX_VAL, coords_to_keys

__all__ = ["check_origin", "check_points", "ray_keys"]

_DBL_MAX = 1.7976931348623157e308


@numba.njit(cache=True, inline="always")
def _key_of(c: float, res_factor: float) -> int:
    """``coordToKeyChecked`` for one coordinate (already rounded to float32); -1 if out of range."""
    s = math.floor(res_factor * c)
    if not (s >= -TREE_MAX_VAL and s < TREE_MAX_VAL):  # also rejects NaN
        return -1
    return np.int64(s) + TREE_MAX_VAL


@numba.njit(cache=True, inline="always")
def _axis_setup(k: int, d: float, o: float, resolution: float, half: float) -> tuple:
    """Step, first t-crossing and t-increment along one axis (``computeRayKeys``'s init)."""
    if d > 0.0:
        border = (np.float64(k - TREE_MAX_VAL) + 0.5) * resolution + half
        return 1, (border - np.float64(o)) / np.float64(d), resolution / abs(np.float64(d))
    if d < 0.0:
        border = (np.float64(k - TREE_MAX_VAL) + 0.5) * resolution - half
        return -1, (border - np.float64(o)) / np.float64(d), resolution / abs(np.float64(d))
    return 0, _DBL_MAX, _DBL_MAX


@numba.njit(cache=True, inline="always")
def _dda_setup(
    ox: float,
    oy: float,
    oz: float,
    ex: float,
    ey: float,
    ez: float,
    kx: int,
    ky: int,
    kz: int,
    resolution: float,
) -> tuple:
    """Initialisation of ``computeRayKeys`` from origin ``o`` (key ``k``) to end ``e`` (float32).

    Reproduces OctoMap's arithmetic: direction normalised in float32 by a float32 length; the first
    voxel border is ``keyToCoord`` (double) plus ``(float)(step * res / 2)``; t-values are doubles.
    Returns (length, steps x/y/z, tmax x/y/z, tdelta x/y/z).
    """
    dx = ex - ox
    dy = ey - oy
    dz = ez - oz
    length = np.float32(math.sqrt(np.float64(dx * dx + dy * dy + dz * dz)))
    half = np.float64(np.float32(resolution * 0.5))
    sx, tmx, tdx = _axis_setup(kx, dx / length, ox, resolution, half)
    sy, tmy, tdy = _axis_setup(ky, dy / length, oy, resolution, half)
    sz, tmz, tdz = _axis_setup(kz, dz / length, oz, resolution, half)
    return length, sx, sy, sz, tmx, tmy, tmz, tdx, tdy, tdz


@numba.njit(cache=True, inline="always")
def _dda_step(
    tmx: float, tmy: float, tmz: float, tdx: float, tdy: float, tdz: float
) -> tuple[int, float, float, float]:
    """One step of ``computeRayKeys``: the axis (0, 1, 2) whose voxel border comes first (ties as
    OctoMap breaks them), and the t-values after crossing it. The caller moves its key, or its
    index, one step along that axis and stops once ``min(tmax) > length``."""
    if tmx < tmy:
        if tmx < tmz:
            return 0, tmx + tdx, tmy, tmz
        return 2, tmx, tmy, tmz + tdz
    if tmy < tmz:
        return 1, tmx, tmy + tdy, tmz
    return 2, tmx, tmy, tmz + tdz


@numba.njit(cache=True, inline="always")
def _dda_key_step(
    kx: int,
    ky: int,
    kz: int,
    sx: int,
    sy: int,
    sz: int,
    tmx: float,
    tmy: float,
    tmz: float,
    tdx: float,
    tdy: float,
    tdz: float,
) -> tuple[int, int, int, float, float, float]:
    """:func:`_dda_step` on a key: (key x/y/z, t-values) after one step."""
    axis, tmx, tmy, tmz = _dda_step(tmx, tmy, tmz, tdx, tdy, tdz)
    if axis == 0:
        kx += sx
    elif axis == 1:
        ky += sy
    else:
        kz += sz
    return kx, ky, kz, tmx, tmy, tmz


@numba.njit(cache=True)
def _clipped_ends(
    points: np.ndarray,
    origin: np.ndarray,
    resolution: float,
    max_range: float,
    clear_range: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per point: effective end (float32), its keys and a status; plus the key box of all rays.

    Status: 0 hit (ray + occupied end), 1 beyond ``max_range`` (ray only), 2 non-finite,
    3 end outside the key range (a finite value too big for float32 included). The clipped end
    follows OctoMap: ``origin + (p - origin).normalized() * (float) clear_range`` (OctoMap's
    ``clear_range`` is ``maxrange``). The key box (lo, hi) spans the origin and every used end key;
    every DDA step changes one key by one.
    """
    n = points.shape[0]
    res_factor = 1.0 / resolution
    ends = np.empty((n, 3), np.float32)
    keys = np.empty((n, 3), np.int64)
    status = np.empty(n, np.int8)
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for a in range(3):
        lo[a] = _key_of(np.float64(origin[a]), res_factor)
        hi[a] = lo[a]
    ox = origin[0]
    oy = origin[1]
    oz = origin[2]
    fmax = np.float32(clear_range)
    for i in range(n):
        if not (
            np.isfinite(points[i, 0]) and np.isfinite(points[i, 1]) and np.isfinite(points[i, 2])
        ):
            status[i] = 2
            continue
        px = np.float32(points[i, 0])
        py = np.float32(points[i, 1])
        pz = np.float32(points[i, 2])
        st = 0
        if max_range >= 0.0:
            dx = px - ox
            dy = py - oy
            dz = pz - oz
            norm = math.sqrt(np.float64(dx * dx + dy * dy + dz * dz))
            if not norm <= max_range:
                st = 1
                fl = np.float32(norm)
                px = ox + (dx / fl) * fmax
                py = oy + (dy / fl) * fmax
                pz = oz + (dz / fl) * fmax
        kx = _key_of(np.float64(px), res_factor)
        ky = _key_of(np.float64(py), res_factor)
        kz = _key_of(np.float64(pz), res_factor)
        if kx < 0 or ky < 0 or kz < 0:
            status[i] = 3
            continue
        status[i] = st
        ends[i, 0] = px
        ends[i, 1] = py
        ends[i, 2] = pz
        keys[i, 0] = kx
        keys[i, 1] = ky
        keys[i, 2] = kz
        lo[0] = min(lo[0], kx)
        lo[1] = min(lo[1], ky)
        lo[2] = min(lo[2], kz)
        hi[0] = max(hi[0], kx)
        hi[1] = max(hi[1], ky)
        hi[2] = max(hi[2], kz)
    return ends, keys, status, lo, hi


def check_origin(origin: ArrayLike, resolution: float) -> NDArray[np.float32]:
    """Return ``origin`` as ``(3,) float32`` or raise :class:`GeometryError` if unusable."""
    try:
        o = np.asarray(origin, dtype=np.float64)
    except (TypeError, ValueError):
        raise GeometryError(f"origin: expected 3 numbers, got {origin!r}") from None
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise GeometryError(f"origin: expected 3 finite numbers, got {origin!r}")
    _, valid = coords_to_keys(o[None], resolution)
    if not valid[0]:
        raise GeometryError(
            f"origin: {o.tolist()} is outside the key range of a map at resolution {resolution}"
        )
    return o.astype(np.float32)


def check_points(points: ArrayLike, what: str = "points") -> NDArray[np.float64]:
    """Return ``points`` as ``(n, 3) float64`` or raise :class:`GeometryError` naming the shape."""
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise GeometryError(f"{what}: expected an (n, 3) array of numbers") from None
    if p.ndim == 1 and p.shape[0] == 3:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3:
        raise GeometryError(f"{what}: expected shape (n, 3), got {p.shape}")
    return p


def ray_keys(origin: ArrayLike, end: ArrayLike, resolution: float) -> NDArray[np.int64]:
    """Free-space keys of one ray, OctoMap's ``computeRayKeys`` (origin in, end voxel out).

    Parameters
    ----------
    origin, end : (3,) float
    resolution : float

    Returns
    -------
    (m, 3) int64
        Keys in traversal order (empty if both points share a voxel).
    """
    o = check_origin(origin, resolution)
    e = check_points(end, "end")
    if e.shape[0] != 1:
        raise GeometryError(f"end: expected one point, got {e.shape[0]}")
    return _single_ray_kernel(e.astype(np.float32), o, float(resolution))


@numba.njit(cache=True)
def _single_ray_kernel(end: np.ndarray, origin: np.ndarray, resolution: float) -> np.ndarray:
    """Traversal-ordered keys of one ray (the same steps as :func:`_dense_trace`)."""
    res_factor = 1.0 / resolution
    kx = _key_of(np.float64(origin[0]), res_factor)
    ky = _key_of(np.float64(origin[1]), res_factor)
    kz = _key_of(np.float64(origin[2]), res_factor)
    ekx = _key_of(np.float64(end[0, 0]), res_factor)
    eky = _key_of(np.float64(end[0, 1]), res_factor)
    ekz = _key_of(np.float64(end[0, 2]), res_factor)
    if ekx < 0 or eky < 0 or ekz < 0 or (ekx == kx and eky == ky and ekz == kz):
        return np.empty((0, 3), np.int64)
    length, sx, sy, sz, tmx, tmy, tmz, tdx, tdy, tdz = _dda_setup(
        origin[0], origin[1], origin[2], end[0, 0], end[0, 1], end[0, 2], kx, ky, kz, resolution
    )
    bound = abs(ekx - kx) + abs(eky - ky) + abs(ekz - kz) + 2
    out = np.empty((bound, 3), np.int64)
    n = 0
    for s in range(bound):
        if s > 0:
            kx, ky, kz, tmx, tmy, tmz = _dda_key_step(
                kx, ky, kz, sx, sy, sz, tmx, tmy, tmz, tdx, tdy, tdz
            )
            if (kx == ekx and ky == eky and kz == ekz) or min(tmx, min(tmy, tmz)) > length:
                break
        out[n, 0] = kx
        out[n, 1] = ky
        out[n, 2] = kz
        n += 1
    return out[:n]
