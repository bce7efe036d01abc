"""The camera's field of view as a convex polytope (the paper's eq. SensorModel, made exact).

A pinhole camera at ``(R, o)`` (world-from-optical rotation, optical centre) sees the pyramid
bounded by four side planes through ``o`` and a far plane. In the optical frame (OpenCV: z forward,
x right, y down) a point ``p`` is inside iff

    x_lo <= p_x / p_z <= x_hi,   y_lo <= p_y / p_z <= y_hi,   p_z <= far_plane_depth,

where ``x_lo, x_hi, y_lo, y_hi`` are the normalised image-plane extents (``u = fx x/z + cx``
spans the pixel edges ``[0, width]``). An ellipsoid is inside iff its support in every outward
face normal is below the face offset (DESIGN.md section 4, "Camera frustum"): that replaces the
paper's "transformed FOV vs unit ball" test of eq. NLPElipseInclude with an exact, smooth one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from secure3d.errors import ConfigError, GeometryError
from secure3d.geometry import backend as B
from secure3d.geometry.backend import ArrayOrSym
from secure3d.geometry.ellipsoid import halfspace_margins
from secure3d.geometry.transforms import check_rotation
from secure3d.validation import is_real

FAR_KINDS = ("depth", "range")


def _finite(value: object, name: str) -> float:
    if not is_real(value, numpy=True):
        raise ConfigError(f"PinholeFrustum.{name}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise ConfigError(f"PinholeFrustum.{name}: must be finite, got {value!r}")
    return v


@dataclass(frozen=True)
class PinholeFrustum:
    """Field of view of a pinhole camera, in its optical frame.

    Attributes
    ----------
    hfov : float
        Full horizontal angle (rad), ``2 atan(width / (2 fx))``, in (0, pi). It is the angle
        between the left and right planes when the principal point is centred.
    vfov : float
        Full vertical angle (rad), ``2 atan(height / (2 fy))``, in (0, pi).
    far : float
        Sensor limit (m), > 0: z-depth or Euclidean range, see ``far_kind``.
    far_kind : {"depth", "range"}
        ``"depth"``: the far face is the plane ``z = far``. ``"range"``: points within Euclidean
        range ``far`` are seen; the pyramid is inner-approximated by the far plane at
        ``far * cos(angle to the farthest image corner)``, so every point of it is within range.
    principal_x, principal_y : float
        Principal point as a fraction of the image width / height (``cx / width``, ``cy /
        height``), in [0, 1]; 0.5 (default) is a centred principal point. Off-centre values make
        the side planes asymmetric.
    side_margin, side_offset, side_shrink : float
        The *observed* field of view's side faces (default 0, 0, 0: the image's border). The side
        plane of an image edge at tangent t (``x = t z``) becomes ``x = (t - side_shrink) z +
        side_offset`` (a narrower angle, moved out by ``side_offset`` at depth 0), and a point must
        lie ``side_margin`` (m, 3D) inside it: see
        :func:`secure3d.mapping.observability.observed_sides`.
    near : float
        Depth (m) of a near face ``z >= near``; 0 (default): none.
    """

    hfov: float
    vfov: float
    far: float
    far_kind: Literal["depth", "range"] = "depth"
    principal_x: float = 0.5
    principal_y: float = 0.5
    side_margin: float = 0.0
    side_offset: float = 0.0
    side_shrink: float = 0.0
    near: float = 0.0

    def __post_init__(self) -> None:
        for name in ("hfov", "vfov"):
            v = _finite(getattr(self, name), name)
            if not 0.0 < v < math.pi:
                raise ConfigError(f"PinholeFrustum.{name}: must be in (0, pi) rad, got {v!r}")
            object.__setattr__(self, name, v)
        far = _finite(self.far, "far")
        if not far > 0:
            raise ConfigError(f"PinholeFrustum.far: must be > 0 m, got {self.far!r}")
        object.__setattr__(self, "far", far)
        if self.far_kind not in FAR_KINDS:
            raise ConfigError(
                f"PinholeFrustum.far_kind: must be 'depth' or 'range', got {self.far_kind!r}"
            )
        for name in ("principal_x", "principal_y"):
            v = _finite(getattr(self, name), name)
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"PinholeFrustum.{name}: must be in [0, 1], got {v!r}")
            object.__setattr__(self, name, v)
        for name in ("side_margin", "side_offset", "side_shrink", "near"):
            v = _finite(getattr(self, name), name)
            if not v >= 0.0:
                raise ConfigError(f"PinholeFrustum.{name}: must be >= 0, got {v!r}")
            object.__setattr__(self, name, v)
        x_lo, x_hi, y_lo, y_hi = self.image_extents
        if min(x_hi - x_lo, y_hi - y_lo) <= 2 * self.side_shrink:
            raise ConfigError(
                f"PinholeFrustum.side_shrink: {self.side_shrink!r} closes the field of view"
            )
        if self.near >= self.far_plane_depth:
            raise ConfigError(f"PinholeFrustum.near: {self.near!r} is beyond the far face")

    @classmethod
    def from_intrinsics(
        cls,
        fx: float,
        fy: float,
        width: float,
        height: float,
        far: float,
        far_kind: Literal["depth", "range"] = "depth",
        cx: float | None = None,
        cy: float | None = None,
    ) -> PinholeFrustum:
        """Frustum of a camera with focal lengths ``fx, fy`` (px), image ``width x height`` (px)
        and principal point ``(cx, cy)`` (px, default the image centre ``width/2, height/2``)."""
        vals = {"fx": fx, "fy": fy, "width": width, "height": height}
        for name, v in vals.items():
            if not is_real(v, numpy=True):
                raise ConfigError(f"from_intrinsics: {name} must be a number, got {v!r}")
            if not (math.isfinite(v) and v > 0):
                raise ConfigError(f"from_intrinsics: {name} must be finite and > 0, got {v!r}")
        cx = width / 2 if cx is None else cx
        cy = height / 2 if cy is None else cy
        return cls(
            hfov=2 * math.atan(width / (2 * fx)),
            vfov=2 * math.atan(height / (2 * fy)),
            far=far,
            far_kind=far_kind,
            principal_x=_finite(cx, "principal_x (cx)") / width,
            principal_y=_finite(cy, "principal_y (cy)") / height,
        )

    @property
    def image_extents(self) -> tuple[float, float, float, float]:
        """Normalised image-plane extents ``(x_lo, x_hi, y_lo, y_hi)`` (x/z and y/z of the image
        edges; y points down, so ``y_lo`` is the top edge)."""
        wx = 2 * math.tan(self.hfov / 2)
        wy = 2 * math.tan(self.vfov / 2)
        return (
            -self.principal_x * wx,
            (1 - self.principal_x) * wx,
            -self.principal_y * wy,
            (1 - self.principal_y) * wy,
        )

    @property
    def far_plane_depth(self) -> float:
        """z-depth of the far face (m): ``far`` for ``"depth"``, else the depth at which the
        farthest image corner ray reaches range ``far``."""
        if self.far_kind == "depth":
            return self.far
        x_lo, x_hi, y_lo, y_hi = self.image_extents
        corner = math.sqrt(1 + max(x_lo**2, x_hi**2) + max(y_lo**2, y_hi**2))
        return self.far / corner

    def far_facets(self) -> tuple[np.ndarray, np.ndarray]:
        """Far faces ``(N (k, 3), d (k,))``: one plane z = far for ``"depth"``; for ``"range"`` a
        cap of facets inside the range sphere (the image is split into patches of at most
        :data:`FACET_ANGLE`; the facet of a patch has the unit normal of the patch's central ray u_c
        and offset ``far * min over the patch corners u of u_c . u``, so every point of the patch's
        cone below it is within range). One plane at ``far_plane_depth`` would be sound too, but for
        wide lenses it keeps less than half the range (paper: the isosceles-triangle sensor)."""
        if self.far_kind == "depth":
            return np.array([[0.0, 0.0, 1.0]]), np.array([self.far])
        x_lo, x_hi, y_lo, y_hi = self.image_extents
        nh = max(1, math.ceil(self.hfov / FACET_ANGLE))
        nv = max(1, math.ceil(self.vfov / FACET_ANGLE))
        xs = np.tan(np.linspace(math.atan(x_lo), math.atan(x_hi), nh + 1))
        ys = np.tan(np.linspace(math.atan(y_lo), math.atan(y_hi), nv + 1))
        normals, offsets = [], []
        for i in range(nh):
            for j in range(nv):
                corners = np.array([[x, y, 1.0] for x in xs[i : i + 2] for y in ys[j : j + 2]])
                corners /= np.linalg.norm(corners, axis=1, keepdims=True)
                centre = corners.sum(axis=0)
                centre /= np.linalg.norm(centre)
                normals.append(centre)
                offsets.append(self.far * float((corners @ centre).min()))
        return np.array(normals), np.array(offsets)

    def optical_halfspaces(self) -> tuple[np.ndarray, np.ndarray]:
        """Faces in the optical frame: ``(N (n, 3), d (n,))`` with unit outward rows, inside iff
        ``N p <= d``. Order: right, left, bottom, top (side planes: through the optical centre
        unless the sides are those of an observed field of view, see ``side_margin``), the near
        face if ``near > 0``, then the far faces (:meth:`far_facets`: one for ``"depth"``, a cap
        of facets for ``"range"``)."""
        x_lo, x_hi, y_lo, y_hi = self.image_extents
        s = self.side_shrink
        N = np.array(
            [
                [1.0, 0.0, -(x_hi - s)],
                [-1.0, 0.0, x_lo + s],
                [0.0, 1.0, -(y_hi - s)],
                [0.0, -1.0, y_lo + s],
            ]
        )
        norm = np.linalg.norm(N, axis=1)
        N /= norm[:, None]
        d = self.side_offset / norm - self.side_margin
        if self.near > 0.0:
            N, d = np.vstack([N, [[0.0, 0.0, -1.0]]]), np.append(d, -self.near)
        far_N, far_d = self.far_facets()
        return np.vstack([N, far_N]), np.concatenate([d, far_d])

    def side_plane_angles(self) -> tuple[float, float, float, float]:
        """``(sin_h, cos_h, sin_v, cos_v)``: the side planes' unit normals in the optical frame are
        ``(+-cos, 0, -sin)`` (horizontal pair) and ``(0, +-cos, -sin)`` (vertical pair), for a
        centred principal point; the image's half angles, less ``side_shrink`` in tangent. (The
        certificate's camera margin reads these, independently of :meth:`optical_halfspaces`.)"""
        out: list[float] = []
        for half in (0.5 * self.hfov, 0.5 * self.vfov):
            if self.side_shrink == 0.0:  # the image's own angles, as the certificate always had
                out += [float(np.sin(half)), float(np.cos(half))]
            else:
                t = float(np.tan(half)) - self.side_shrink
                out += [t / float(np.hypot(1.0, t)), 1.0 / float(np.hypot(1.0, t))]
        return out[0], out[1], out[2], out[3]

    @property
    def n_faces(self) -> int:
        """Number of half-spaces of the field of view (4 sides, the near face if any, plus the far
        faces)."""
        return 4 + (self.near > 0.0) + len(self.far_facets()[1])


#: Largest angular size of one far facet of a range-limited frustum (rad).
FACET_ANGLE = math.radians(30.0)


def _check_frustum(frustum: object) -> PinholeFrustum:
    if not isinstance(frustum, PinholeFrustum):
        raise GeometryError(f"frustum: expected a PinholeFrustum, got {type(frustum).__name__}")
    return frustum


def _pose(R: ArrayOrSym, origin: ArrayOrSym):
    """Validated numpy pose, or CasADi pose (R 3x3, origin column)."""
    if B.is_symbolic(R, origin):
        return True, B.matrix(R, True), B.vector(origin, True)
    R = check_rotation(R)
    o = np.asarray(origin, dtype=float)
    if o.shape != R.shape[:-1] or not np.all(np.isfinite(o)):
        raise GeometryError(
            f"origin: expected finite shape {R.shape[:-1]} to match R {R.shape}, got {o.shape}"
        )
    return False, R, o


def frustum_halfspaces(
    world_from_optical_R: ArrayOrSym, origin: ArrayOrSym, frustum: PinholeFrustum
) -> tuple[ArrayOrSym, ArrayOrSym]:
    """World-frame faces ``A y <= b`` of the camera's field of view, numpy or CasADi.

    ``A = N R^T`` (unit rows, outward) and ``b = A o + d`` with the optical-frame faces ``(N, d)``
    of :meth:`PinholeFrustum.optical_halfspaces`: the four side planes pass through the camera
    centre ``o``. This is the paper's eq. SensorModel; the planner calls it with a symbolic pose.

    Parameters
    ----------
    world_from_optical_R : (3, 3) or (N, 3, 3) float, or CasADi 3x3
    origin : (3,) or (N, 3) float, or CasADi (3, 1): the optical centre in the world (m).
    frustum : PinholeFrustum

    Returns
    -------
    A : (F, 3) or (N, F, 3) float, or CasADi (F, 3), F = frustum.n_faces
    b : (F,) or (N, F) float, or CasADi (F, 1)
    """
    frustum = _check_frustum(frustum)
    sym, R, o = _pose(world_from_optical_R, origin)
    N, d = frustum.optical_halfspaces()
    A = B.matmul(N, B.transpose(R))
    return A, B.matvec(A, o) + B.vector(d, sym)


def frustum_corners(R: object, origin: object, frustum: PinholeFrustum) -> np.ndarray:
    """Apex and the four far-face corners in the world, for drawing (numpy).

    Returns
    -------
    (5, 3) float (or (N, 5, 3) for a batch of poses): apex, then the corners at image
    (left, top), (right, top), (right, bottom), (left, bottom).
    """
    frustum = _check_frustum(frustum)
    _, R, o = _pose(R, origin)
    x_lo, x_hi, y_lo, y_hi = frustum.image_extents
    depth = frustum.far_plane_depth
    p_opt = depth * np.array(
        [[0, 0, 0], [x_lo, y_lo, 1], [x_hi, y_lo, 1], [x_hi, y_hi, 1], [x_lo, y_hi, 1]],
        dtype=float,
    )
    return o[..., None, :] + p_opt @ np.swapaxes(R, -1, -2)


def points_in_frustum(
    R: object, origin: object, frustum: PinholeFrustum, points: object, margin: float = 0.0
) -> np.ndarray:
    """Which points lie in the field of view, at least ``margin`` (m) inside every face (numpy).

    For ``far_kind="range"`` this is the inner polytope, consistent with the planner's constraint.

    Parameters
    ----------
    R : (3, 3) float, world-from-optical rotation.
    origin : (3,) float
    frustum : PinholeFrustum
    points : (n, 3) float
    margin : float
        Required clearance from every face (m); negative values inflate the frustum.

    Returns
    -------
    (n,) bool
    """
    frustum = _check_frustum(frustum)
    _, R, o = _pose(R, origin)
    if R.ndim != 2:
        raise GeometryError(f"points_in_frustum: expects one pose, got R of shape {R.shape}")
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    N, d = frustum.optical_halfspaces()
    p_opt = (p - o) @ R
    return np.all(p_opt @ N.T <= d - float(margin), axis=-1)


def ellipsoid_in_frustum_margin(
    center: ArrayOrSym,
    shape: ArrayOrSym,
    R: ArrayOrSym,
    origin: ArrayOrSym,
    frustum: PinholeFrustum,
) -> ArrayOrSym:
    """Containment margin of the ellipsoid in the field of view (m), numpy or CasADi.

    ``min_i (b_i - A_i c - |M A_i|)`` over the five faces: ``>= 0`` iff the whole ellipsoid is
    seen (eq. SensorModel). The CasADi result is a non-smooth ``mmin``; an NLP should constrain the
    five entries of ``halfspace_margins(center, shape, *frustum_halfspaces(R, origin, frustum))``.

    Returns
    -------
    float (``(N,)`` for a numpy batch of poses and ellipsoids), or CasADi scalar.
    """
    A, b = frustum_halfspaces(R, origin, frustum)
    return B.vmin(halfspace_margins(center, shape, A, b))
