"""Depth images to world points: the camera side of a map update (pinhole model, OpenCV axes).

Split from :mod:`secure3d.mapping.occupancy` (which re-exports both public functions): the map
takes points; this module makes them from a z-depth image and knows how far a depth camera's
farthest corner reaches.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import ConfigError, GeometryError

__all__ = ["depth_image_points", "far_plane_reach"]


def depth_image_points(
    depth: ArrayLike,
    intrinsics: ArrayLike,
    cam2world: ArrayLike,
    origin: ArrayLike,
    max_range: float | None,
    far_kind: str = "range",
) -> NDArray[np.float64]:
    """World points of a z-depth image, ready for :meth:`OccupancyMap.insert_point_cloud`.

    Pixel ``(u, v)`` (column, row) looks along ``((u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, 1)``
    in the camera frame (OpenCV axes: x right, y down, z forward; pixel centres, as Open3D's
    ``RaycastingScene.create_rays_pinhole``), rotated to the world by ``cam2world``.

    Parameters
    ----------
    depth : (H, W) float
        z-depth (m). Finite ``d > 0``: a hit at ``d`` times the pixel's ray. ``inf`` (and, for
        ``far_kind="depth"``, ``d > max_range``): no return, mapped to a point on the ray beyond
        every hit the sensor can report (see ``far_kind``), so that OctoMap's rule only clears
        space along it. NaN, ``d <= 0``, or no return without ``max_range``: NaN (skipped).
    intrinsics : (3, 3) float or (4,) float
        Camera matrix K, or ``(fx, fy, cx, cy)`` in pixels.
    cam2world : (3, 3) float
        Rotation from camera to world frame.
    origin : (3,) float
        Camera centre in the world (m).
    max_range : float or None
        Maximum sensing range (m).
    far_kind : ``"range"`` or ``"depth"``
        Whether ``max_range`` limits the Euclidean range (no returns placed at ``2 max_range + 1``)
        or the z-depth (placed at ``2 R + 1``, ``R`` the farthest point of the image's far plane,
        :func:`far_plane_reach`).

    Returns
    -------
    (H * W, 3) float64
        Row-major over pixels.
    """
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim != 2:
        raise GeometryError(f"depth: expected an (H, W) image, got shape {d.shape}")
    fx, fy, cx, cy = _intrinsics(intrinsics)
    if far_kind not in ("range", "depth"):
        raise ConfigError(f"far_kind: must be 'range' or 'depth', got {far_kind!r}")
    rot = np.asarray(cam2world, dtype=np.float64)
    if rot.shape != (3, 3) or not np.all(np.isfinite(rot)):
        raise GeometryError(f"cam2world: expected a finite (3, 3) rotation, got shape {rot.shape}")
    if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
        raise GeometryError("cam2world: not a rotation matrix (R^T R != I or det < 0)")
    o = np.asarray(origin, dtype=np.float64)
    if o.shape != (3,):
        raise GeometryError(f"origin: expected 3 numbers, got shape {o.shape}")
    # A no-return pixel becomes a point beyond every possible hit (-1: no max_range, skipped).
    far, depth_limit = -1.0, np.inf
    if max_range is not None:
        if far_kind == "depth":
            depth_limit = float(max_range)
            far = 2.0 * far_plane_reach(d.shape, (fx, fy, cx, cy), max_range) + 1.0
        else:
            far = 2.0 * max_range + 1.0
    return _depth_points_kernel(np.ascontiguousarray(d), fx, fy, cx, cy, rot, o, far, depth_limit)


def _intrinsics(intrinsics: ArrayLike) -> tuple[float, float, float, float]:
    k = np.asarray(intrinsics, dtype=np.float64)
    if k.shape == (3, 3):
        fx, fy, cx, cy = k[0, 0], k[1, 1], k[0, 2], k[1, 2]
    elif k.shape == (4,):
        fx, fy, cx, cy = k
    else:
        raise GeometryError(f"intrinsics: expected K (3, 3) or (fx, fy, cx, cy), got {k.shape}")
    if not (np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0):
        raise GeometryError(f"intrinsics: need finite fx, fy > 0, got {k.tolist()}")
    return float(fx), float(fy), float(cx), float(cy)


def far_plane_reach(shape: tuple[int, int], intrinsics: ArrayLike, max_depth: float) -> float:
    """Largest Euclidean range (m) of a pixel ray of an (H, W) image at z-depth ``max_depth``: its
    farthest corner pixel. A z-depth-limited camera can report hits this far away."""
    fx, fy, cx, cy = _intrinsics(intrinsics)
    if len(shape) != 2 or min(shape) < 1:
        raise GeometryError(f"far_plane_reach: shape must be (H, W) >= 1, got {tuple(shape)}")
    if not (math.isfinite(max_depth) and max_depth > 0):
        raise ConfigError(f"far_plane_reach: max_depth must be finite and > 0, got {max_depth!r}")
    h, w = shape
    tx = max(abs(0.5 - cx), abs(w - 0.5 - cx)) / fx
    ty = max(abs(0.5 - cy), abs(h - 0.5 - cy)) / fy
    return float(max_depth) * math.sqrt(1.0 + tx * tx + ty * ty)


@numba.njit(cache=True)
def _depth_points_kernel(
    d: np.ndarray,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    rot: np.ndarray,
    o: np.ndarray,
    far: float,
    depth_limit: float,
) -> np.ndarray:
    """World points of a depth image, one pass over the pixels (see :func:`depth_image_points`):
    no returns (``inf``, or beyond ``depth_limit``) at scale ``far`` if ``far > 0``."""
    h, w = d.shape
    out = np.empty((h * w, 3))
    for v in range(h):
        ry = (v + 0.5 - cy) / fy
        for u in range(w):
            i = v * w + u
            s = d[v, u]
            if (np.isposinf(s) or (np.isfinite(s) and s > depth_limit)) and far > 0.0:
                s = far
            if not (s > 0.0 and np.isfinite(s)):
                out[i, 0] = np.nan
                out[i, 1] = np.nan
                out[i, 2] = np.nan
                continue
            rx = (u + 0.5 - cx) / fx
            px, py, pz = rx * s, ry * s, s
            out[i, 0] = o[0] + (rot[0, 0] * px + rot[0, 1] * py + rot[0, 2] * pz)
            out[i, 1] = o[1] + (rot[1, 0] * px + rot[1, 1] * py + rot[1, 2] * pz)
            out[i, 2] = o[2] + (rot[2, 0] * px + rot[2, 1] * py + rot[2, 2] * pz)
    return out


def optical_axis(cam2world: ArrayLike) -> NDArray[np.float64]:
    """(3,) the camera's optical axis (its z) in the world: the unit third column of
    ``cam2world`` (3, 3)."""
    R = np.asarray(cam2world, dtype=np.float64)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise GeometryError(f"cam2world: expected a finite (3, 3) rotation, got shape {R.shape}")
    z = R[:, 2]
    n = float(np.linalg.norm(z))
    if not n > 0.0:
        raise GeometryError("cam2world: its third column (the optical axis) is zero")
    return z / n
