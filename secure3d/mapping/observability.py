"""How far a depth camera's frames are guaranteed to see an obstacle: the *observed range*.

The paper's safety theorem assumes continuous perception: whatever lies in the field of view is
seen. A pixel grid only samples it. :func:`observed_range` gives the far limit out to which every
obstacle of at least a stated size (``min_obstacle_size``) is hit by some ray of every frame, and
so (with sticky hits, :mod:`secure3d.mapping.hits`) is a known obstacle from that frame on. The
planner's frustum and the certificate both cut the field of view there (DESIGN.md section 7).
"""

from __future__ import annotations

import math

from secure3d.errors import ConfigError
from secure3d.geometry.frustum import PinholeFrustum
from secure3d.validation import is_real

#: Default smallest obstacle (m) the guarantee covers (see PlannerSpec.min_obstacle_size for why).
DEFAULT_MIN_OBSTACLE_SIZE = 0.15
#: Per-frame probability of missing such an obstacle that dropout may leave (see
#: :func:`observed_range`): one in a million frames.
DROPOUT_MISS_PROBABILITY = 1e-6


def _number(value: object, name: str, *, positive: bool = True) -> float:
    if not is_real(value):
        raise ConfigError(f"observed_range: {name} must be a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or (positive and v <= 0.0):
        raise ConfigError(f"observed_range: {name} must be finite and > 0, got {value!r}")
    return v


def rays_needed(dropout: float, miss_probability: float = DROPOUT_MISS_PROBABILITY) -> int:
    """Rays an obstacle must meet so that losing all of them to dropout (each pixel independently
    with probability ``dropout``) has probability at most ``miss_probability``: 1 without dropout,
    else ``ceil(log(miss_probability) / log(dropout))``."""
    p = _number(dropout, "dropout", positive=False)
    if not 0.0 <= p < 1.0:
        raise ConfigError(f"observed_range: dropout must be in [0, 1), got {dropout!r}")
    eps = _number(miss_probability, "miss_probability")
    if not eps < 1.0:
        raise ConfigError(f"observed_range: miss_probability must be in (0, 1), got {eps!r}")
    if p == 0.0:
        return 1
    return max(1, math.ceil(math.log(eps) / math.log(p) - 1e-12))


def observed_range(
    fx: float,
    fy: float,
    max_range: float,
    far_kind: str,
    resolution: float,
    *,
    min_obstacle_size: float = DEFAULT_MIN_OBSTACLE_SIZE,
    discretize: bool = False,
    dropout: float = 0.0,
    miss_probability: float = DROPOUT_MISS_PROBABILITY,
    edge_allowance: bool = False,
) -> float:
    """The far limit (m, in the camera's ``far_kind``) out to which a frame surely hits every
    obstacle of size ``min_obstacle_size`` inside its field of view (with ``edge_allowance``: every
    such obstacle touching a point inside it, its ball straddling the sensor's limit or not).

    Parameters
    ----------
    fx, fy : float
        Focal lengths (pixels); pixel centres at ``u + 0.5``, ``v + 0.5`` (Open3D's convention).
    max_range : float
        The sensor's limit (m): z-depth (``far_kind="depth"``) or Euclidean range (``"range"``).
    far_kind : {"depth", "range"}
    resolution : float
        Voxel edge of the robot's map (m).
    min_obstacle_size : float
        w (m): the guarantee covers every obstacle that contains a ball of diameter w (a pole, wire
        or plank at least w thick, a crate...).
    discretize : bool
        Frames inserted with OctoMap's ``discretize`` (one ray per end voxel, to its centre).
    dropout : float
        Fraction of pixels lost, each independently, in [0, 1).
    miss_probability : float
        With dropout, the per-frame probability of missing such an obstacle that is accepted.

    Returns
    -------
    float
        ``min(max_range, z_res - w / 2, z_vox)`` (> 0; with ``edge_allowance`` the sensor's
        limits count w / 2 short, w for ``"range"``): z_res from the pixel pitch (and dropout,
        :func:`_pixel_pitch_depth`), z_vox from the discretisation (:func:`_discretised_far`).

    Notes
    -----
    *Far face.* The planner and the certificate see a point (of a manoeuvre's body ball) inside the
    field of view; an obstacle touching it contains a ball of diameter w through that point, whose
    centre may lie w / 2 deeper. The far limit is therefore ``z_res - w / 2``. The pixel ray
    through that ball's centre plane reaches it at most w / 2 deeper than q (w further for a
    Euclidean range), so with ``edge_allowance`` a sensor limit counts ``max_range - w / 2``
    (``- w`` for ``"range"``); without it a ball straddling the limit is covered once it is
    within range. The side faces' allowance is :func:`observed_sides`.

    *Range.* A Euclidean limit bounds z-depth too, so ``min(max_range, z_res)`` as a range is
    sound. *Noise* moves a hit along its ray, within the noise of the surface.
    """
    fx = _number(fx, "fx")
    fy = _number(fy, "fy")
    far = _number(max_range, "max_range")
    if far_kind not in ("depth", "range"):
        raise ConfigError(f"observed_range: far_kind must be 'depth' or 'range', got {far_kind!r}")
    res = _number(resolution, "resolution")
    w = _number(min_obstacle_size, "min_obstacle_size")
    z_res = _pixel_pitch_depth(fx, fy, w, rays_needed(dropout, miss_probability))
    if discretize and far_kind == "range":
        far = _discretised_far(far, res, max_range, resolution)
    z_obs = z_res - 0.5 * w
    if edge_allowance:
        far -= w if far_kind == "range" else 0.5 * w
    if far <= 0.0:
        raise ConfigError(
            f"observed_range: max_range {max_range!r} m leaves no surely observed depth for"
            f" min_obstacle_size {min_obstacle_size!r} m"
        )
    if z_obs <= 0.0:
        raise ConfigError(
            f"observed_range: min_obstacle_size {min_obstacle_size!r} is too small for this camera"
            f" (fx {fx:g}, fy {fy:g} px): no depth is surely observed"
        )
    return min(far, z_obs)


def observed_sides(
    fx: float,
    fy: float,
    min_obstacle_size: float = DEFAULT_MIN_OBSTACLE_SIZE,
    *,
    dropout: float = 0.0,
    miss_probability: float = DROPOUT_MISS_PROBABILITY,
) -> tuple[float, float, float, float]:
    """The observed field of view's side and near faces, ``(margin, offset, shrink, near)`` as
    :class:`~secure3d.geometry.frustum.PinholeFrustum` takes them (``side_margin``,
    ``side_offset``, ``side_shrink``, ``near``): the side faces' counterpart of the far face's
    ``- w / 2`` in :func:`observed_range`.

    An obstacle touching a point q counted as seen contains a ball of diameter w through q; its
    centre c lies within w / 2 of q. Some pixel ray meets that ball if, in the depth plane of c,
    a pixel centre lies within w / 2 of c. The pixel centres there form a lattice of pitch
    ``(p_x, p_y) = (z / fx, z / fy)`` inset half a pitch from the image's edges, so a c inside the
    image's rectangle grown by g on every side (corners included) has one within
    ``sqrt((g + p_x / 2)^2 + (g + p_y / 2)^2)``, which is at most w / 2 for

        g(z) = (sqrt(2 w^2 - (p_x - p_y)^2) - p_x - p_y) / 4,

    concave in z, from ``w / (2 sqrt 2)`` at z = 0 to 0 at the pixel-pitch depth z_res (where the
    far face already stops c). Its chord ``offset - shrink z``, with ``offset = w / (2 sqrt 2)``
    and ``shrink = offset / z_res``, lies below it, so c is hit wherever it lies inside the
    planes ``x = (t - shrink) z + offset`` of the image's edges (tangents t); q must then lie
    ``margin = w / 2`` inside them (3D distance), and ``near = w / 2`` deep so that c lies in
    front of the camera.

    With dropout (``m x m`` rays on the ball, :func:`_pixel_pitch_depth`) the square of side
    ``w / sqrt 2`` round c must lie inside the image: ``margin = w / 2 + w / (2 sqrt 2)`` inside
    the image's own planes (``offset = shrink = 0``).
    """
    fx = _number(fx, "fx")
    fy = _number(fy, "fy")
    w = _number(min_obstacle_size, "min_obstacle_size")
    half = 0.5 * w
    if rays_needed(dropout, miss_probability) > 1:
        return half * (1.0 + 1.0 / math.sqrt(2.0)), 0.0, 0.0, half
    offset = half / math.sqrt(2.0)
    return half, offset, offset / _pixel_pitch_depth(fx, fy, w, 1), half


def _pixel_pitch_depth(fx: float, fy: float, w: float, n: int) -> float:
    """z_res (m): the largest z-depth at which at least ``n`` pixel rays meet every ball of
    diameter ``w`` in the field of view (focal lengths ``fx``, ``fy`` in pixels).

    *Pixel pitch.* At z-depth z the pixel rays cross the plane ``{depth = z}`` in a rectangular
    lattice of pitch ``(z / fx, z / fy)``, and every lattice point inside the field of view is a
    pixel centre. A ball of diameter w centred at depth z cuts that plane in a disc of diameter w,
    and a disc at least as wide as a lattice cell's diagonal ``z sqrt(fx^-2 + fy^-2)`` contains a
    lattice point wherever it lies. So some ray meets the ball, and its first hit is the ball or an
    obstacle in front of it (then that one blocks the view and is hit instead), whenever

        z <= z_res = w / sqrt(fx^-2 + fy^-2)        (= w f / sqrt(2) for fx = fy = f).

    Off the optical axis the lattice is the same in the plane, so no pixel does worse. (A band,
    like a long pole seen side on, needs only ``z <= w f``; the disc is the worst case.)

    *Dropout.* A frame then still misses the ball if every ray through it is lost. Requiring
    ``n = rays_needed(dropout, miss_probability)`` rays keeps that below ``miss_probability`` per
    frame: the disc contains a square of side ``w / sqrt(2)``, which holds at least ``m x m``
    lattice points when both pitches are at most ``w / (sqrt(2) m)``; with ``m = ceil(sqrt(n))``,

        z_res = w min(fx, fy) / (sqrt(2) m)         (p > 0; a statement per frame, not a certainty).
    """
    if n == 1:
        return w / math.hypot(1.0 / fx, 1.0 / fy)
    return w * min(fx, fy) / (math.sqrt(2.0) * math.ceil(math.sqrt(n)))


def _discretised_far(far: float, res: float, max_range: float, resolution: float) -> float:
    """z_vox (m): the range limit ``far`` of frames inserted with ``discretize``, at voxel edge
    ``res`` (``max_range`` and ``resolution`` as the caller gave them, for the error message).

    *Discretisation.* ``discretize`` casts one ray per *end voxel*, to its centre; every end voxel is
    still marked occupied, so it loses no hit of the full pixel grid (a thin obstacle is never
    skipped), except where the centre falls beyond the clipping range while the hit lies within.
    :meth:`~secure3d.mapping.occupancy.OccupancyMap.insert_depth_image` clips z-depth frames a voxel
    beyond the far corner, so none is lost there; a range-limited frame loses hits up to half a
    voxel diagonal inside ``max_range``, so ``z_vox = max_range - (sqrt(3) / 2) resolution`` then.
    """
    far -= 0.5 * math.sqrt(3.0) * res
    if far <= 0.0:
        raise ConfigError(
            f"observed_range: max_range {max_range!r} is within half a voxel diagonal of the"
            f" sensor at resolution {resolution!r}: nothing is surely observed"
        )
    return far


def observed_frustum(
    camera: object, resolution: float, min_obstacle_size: float, *, edge_allowance: bool = False
) -> PinholeFrustum:
    """The camera's field of view cut at the *observed range* (:func:`observed_range`), from a
    camera spec (``fx``, ``fy``, ``hfov``, ``vfov``, ``max_range``, ``far_kind``, ``discretize``,
    ``dropout``: :class:`secure3d.world.spec.CameraSpec`) and the map's voxel edge. With
    ``edge_allowance`` the sensor's limit counts w / 2 short, the side faces move inwards and a
    near face is added (:func:`observed_sides`): then an obstacle of ``min_obstacle_size``
    touching any point counted as seen is surely hit, its ball straddling the view's edge or not.
    The NLP's visibility rows, the certificate's views and the tracking guard all read it from the
    planning problem."""
    c = camera
    far = observed_range(
        c.fx,
        c.fy,
        c.max_range,
        c.far_kind,
        resolution,
        min_obstacle_size=min_obstacle_size,
        discretize=c.discretize,
        dropout=c.dropout,
        edge_allowance=bool(edge_allowance),
    )
    sides = (0.0, 0.0, 0.0, 0.0)
    if edge_allowance:
        sides = observed_sides(c.fx, c.fy, min_obstacle_size, dropout=c.dropout)
    margin, offset, shrink, near = sides
    return PinholeFrustum(
        hfov=c.hfov,
        vfov=c.vfov,
        far=far,
        far_kind=c.far_kind,
        side_margin=margin,
        side_offset=offset,
        side_shrink=shrink,
        near=near,
    )
