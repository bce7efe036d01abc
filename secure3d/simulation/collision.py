"""Collision checking of the realised motion against the true world, with python-fcl.

The body is a sphere of radius ``r``. Between two simulation steps it sweeps a capsule around the
segment ``p0 -> p1``; checking that capsule is exact for straight motion between samples and cheap
(DESIGN.md section 5: ``fcl.continuousCollide`` against meshes segfaults or silently misses, so we
never use it). The capsule's local axis is z, centred at its origin, with ``lz`` the length of the
segment (the hemispherical caps come on top).

Obstacles and how fcl sees them:

- boxes and voxel boxes: ``fcl.Box``, solid;
- convex mesh obstacles: ``fcl.Convex``, solid (signed distances are exact);
- non-convex mesh obstacles: ``fcl.BVHModel``, a *surface*. A body wholly inside such a mesh does
  not touch it; the realised path enters from outside, so the swept capsule of the step that
  crosses the surface reports the contact (see :meth:`CollisionWorld.first_contact`).

All obstacles live in one ``fcl.DynamicAABBTreeCollisionManager``, so a query costs a broad-phase
descent plus exact tests against the few obstacles whose bounding boxes overlap the query.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import trimesh

from secure3d._deps import fcl as _fcl
from secure3d.errors import GeometryError
from secure3d.simulation.scene import (
    VOXEL_NAME,
    by_voxel_content,
    merged_voxel_boxes,
)
from secure3d.world.spec import Box, MeshObstacle

#: Segments shorter than this (m) are checked as a sphere: a capsule of zero length is a sphere and
#: fcl's capsule code divides by the length when building its frame.
_MIN_SEGMENT = 1e-9
#: Slack (m) a known clearance must have over a step's length before the swept check is skipped:
#: far above the error of fcl's distances (exact for spheres against boxes, ~1e-5 m through GJK).
SWEEP_SKIP_MARGIN = 1e-3


def _check_point(p: object, what: str) -> np.ndarray:
    q = np.asarray(p, dtype=float)
    if q.shape != (3,) or not np.all(np.isfinite(q)):
        raise GeometryError(f"{what}: expected 3 finite numbers, got {p!r}")
    return q


def _check_radius(r: object) -> float:
    try:
        v = float(r)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise GeometryError(f"radius: expected a number, got {r!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise GeometryError(f"radius: must be finite and > 0, got {r!r}")
    return v


def rotation_z_to(direction: np.ndarray) -> np.ndarray:
    """A rotation matrix (3, 3) taking the local z axis to the unit vector along ``direction``.

    Used to align a capsule (axis z in fcl) with a segment. ``direction`` : (3,) float, nonzero.
    """
    d = np.asarray(direction, dtype=float)
    z0, z1, z2 = (float(v) for v in d / np.linalg.norm(d))
    # The world axis least aligned with z keeps the cross product well conditioned; x = axis x z
    # written out (called once per simulation step, where np.cross's overhead showed).
    a0, a1, a2 = abs(z0), abs(z1), abs(z2)
    if a0 <= a1 and a0 <= a2:
        x0, x1, x2 = 0.0, -z2, z1
    elif a1 <= a2:
        x0, x1, x2 = z2, 0.0, -z0
    else:
        x0, x1, x2 = -z1, z0, 0.0
    n = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    x0, x1, x2 = x0 / n, x1 / n, x2 / n
    y0, y1, y2 = z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0
    return np.array([[x0, y0, z0], [x1, y1, z1], [x2, y2, z2]])


def _voxel_shapes(voxel_boxes: np.ndarray) -> tuple[list[Any], list[Any]]:
    """fcl boxes and their transforms for voxel boxes (n, 2, 3), merged first
    (:func:`~secure3d.simulation.scene.merged_voxel_boxes`). Shared by the collision worlds of one
    voxel world (fcl shapes are immutable, and a static object's transform never changes)."""
    fcl = _fcl()
    vb = merged_voxel_boxes(voxel_boxes)
    shapes = [fcl.Box(*(hi - lo)) for lo, hi in vb]
    return shapes, [fcl.Transform(0.5 * (lo + hi)) for lo, hi in vb]


class CollisionWorld:
    """The true obstacles in an fcl broad-phase manager.

    Parameters
    ----------
    boxes : sequence of :class:`~secure3d.world.spec.Box`
    meshes : sequence of :class:`~secure3d.world.spec.MeshObstacle`
    voxel_boxes : (n, 2, 3) float, optional
        ``[lo, hi]`` of occupied voxels (e.g. an OctoMap world); reported as :data:`VOXEL_NAME`.

    Attributes
    ----------
    names : tuple of str
        Obstacle name of every fcl object, in registration order (voxels repeat ``VOXEL_NAME``).
    """

    def __init__(
        self,
        boxes: Sequence[Box] = (),
        meshes: Sequence[MeshObstacle] = (),
        voxel_boxes: np.ndarray | None = None,
    ) -> None:
        fcl = _fcl()
        self._fcl = fcl
        geoms: list[Any] = []
        names: list[str] = []
        surface: list[bool] = []
        transforms: list[Any] = []
        for b in boxes:
            lo, hi = np.asarray(b.lo), np.asarray(b.hi)
            geoms.append(fcl.Box(*(hi - lo)))
            transforms.append(fcl.Transform(0.5 * (lo + hi)))
            names.append(b.name)
            surface.append(False)
        for m in meshes:
            geom, is_surface = self._mesh_geometry(m)
            geoms.append(geom)
            transforms.append(fcl.Transform())
            names.append(m.name)
            surface.append(is_surface)
        if voxel_boxes is not None:
            shapes, places = by_voxel_content("fcl", voxel_boxes, _voxel_shapes)  # type: ignore[misc]
            geoms += shapes
            transforms += places
            names += [VOXEL_NAME] * len(shapes)
            surface += [False] * len(shapes)
        self.names: tuple[str, ...] = tuple(names)
        self._surface = np.array(surface, dtype=bool)
        self._geoms = geoms
        self._objects = [fcl.CollisionObject(g, t) for g, t in zip(geoms, transforms, strict=True)]
        # fcl hands back the Python geometry object of the obstacle in contacts and distance
        # results (it keeps it as the object's user data): identity is the only handle it offers.
        self._index_of_geometry = {id(g): i for i, g in enumerate(geoms)}
        self._manager = fcl.DynamicAABBTreeCollisionManager()
        if self._objects:
            self._manager.registerObjects(self._objects)
        self._manager.setup()

    # -- construction helpers -------------------------------------------------------------------

    def _mesh_geometry(self, m: MeshObstacle) -> tuple[Any, bool]:
        fcl = self._fcl
        tm = trimesh.Trimesh(np.array(m.vertices), np.array(m.faces), process=False)
        if tm.is_convex:
            faces = np.hstack([np.full((len(tm.faces), 1), 3), tm.faces]).ravel()
            return fcl.Convex(np.asarray(tm.vertices, dtype=float), len(tm.faces), faces), False
        bvh = fcl.BVHModel()
        bvh.beginModel(len(tm.vertices), len(tm.faces))
        bvh.addSubModel(np.asarray(tm.vertices, dtype=float), np.asarray(tm.faces))
        bvh.endModel()
        return bvh, True

    # -- queries ---------------------------------------------------------------------------------

    @property
    def empty(self) -> bool:
        """True when the world has no obstacles."""
        return not self._objects

    def _sphere(self, p: np.ndarray, r: float) -> Any:
        fcl = self._fcl
        return fcl.CollisionObject(fcl.Sphere(r), fcl.Transform(p))

    def _swept(self, p0: np.ndarray, p1: np.ndarray, r: float) -> Any:
        d = p1 - p0
        length = float(np.linalg.norm(d))
        if length < _MIN_SEGMENT:
            return self._sphere(0.5 * (p0 + p1), r)
        fcl = self._fcl
        return fcl.CollisionObject(
            fcl.Capsule(r, length), fcl.Transform(rotation_z_to(d), 0.5 * (p0 + p1))
        )

    def _obstacle_index(self, g1: Any, g2: Any) -> int:
        """Index of whichever of two fcl geometries is one of ours (the other is the query)."""
        i = self._index_of_geometry.get(id(g1))
        return self._index_of_geometry[id(g2)] if i is None else i

    def _collides(self, query: Any) -> bool:
        if self.empty:
            return False
        fcl = self._fcl
        data = fcl.CollisionData(request=fcl.CollisionRequest())
        self._manager.collide(query, data, fcl.defaultCollisionCallback)
        return bool(data.result.is_collision)

    def _touching(self, query: Any) -> tuple[str, ...]:
        if self.empty:
            return ()
        fcl = self._fcl
        hit: set[int] = set()

        def callback(o1: Any, o2: Any, _data: Any) -> bool:
            res = fcl.CollisionResult()
            fcl.collide(o1, o2, fcl.CollisionRequest(enable_contact=True), res)
            hit.update(self._obstacle_index(c.o1, c.o2) for c in res.contacts)
            return False  # keep going: report every obstacle touched

        self._manager.collide(query, None, callback)
        return tuple(dict.fromkeys(self.names[i] for i in sorted(hit)))

    def sphere_collides(self, p: np.ndarray, r: float) -> bool:
        """True if the ball of radius ``r`` (m) at ``p`` : (3,) float touches an obstacle."""
        return self._collides(self._sphere(_check_point(p, "p"), _check_radius(r)))

    def swept_collides(
        self, p0: np.ndarray, p1: np.ndarray, r: float, clearance0: float | None = None
    ) -> bool:
        """True if a ball of radius ``r`` moving straight from ``p0`` to ``p1`` touches an obstacle.

        Checks the capsule swept by the ball (DESIGN.md section 5); a degenerate segment is a ball.
        ``clearance0``, if given, is :meth:`clearance` of the ball at ``p0``: every point of the
        capsule lies within ``r + |p1 - p0|`` of ``p0``, so a clearance above ``|p1 - p0|`` (plus
        :data:`SWEEP_SKIP_MARGIN`) proves there is no contact without the capsule query.
        """
        q0, q1 = _check_point(p0, "p0"), _check_point(p1, "p1")
        rad = _check_radius(r)
        if clearance0 is not None:
            if isinstance(clearance0, bool) or not isinstance(clearance0, (int, float, np.number)):
                raise GeometryError(f"clearance0: expected a number or None, got {clearance0!r}")
            step = math.sqrt((q1[0] - q0[0]) ** 2 + (q1[1] - q0[1]) ** 2 + (q1[2] - q0[2]) ** 2)
            if float(clearance0) > step + SWEEP_SKIP_MARGIN:
                return False
        return self._collides(self._swept(q0, q1, rad))

    def contact_obstacles(self, p0: np.ndarray, p1: np.ndarray, r: float) -> tuple[str, ...]:
        """Names of the obstacles the swept capsule ``p0 -> p1`` (radius ``r``) touches, sorted by
        registration order, without repeats; empty when there is no contact."""
        q0, q1 = _check_point(p0, "p0"), _check_point(p1, "p1")
        return self._touching(self._swept(q0, q1, _check_radius(r)))

    def nearest(self, p: np.ndarray, r: float) -> tuple[float, str | None]:
        """Clearance of the ball (``p``, ``r``) and the name of the nearest obstacle.

        Returns ``(inf, None)`` in an empty world. See :meth:`clearance` for the sign convention.
        """
        q, rad = _check_point(p, "p"), _check_radius(r)
        if self.empty:
            return float("inf"), None
        fcl = self._fcl
        query = self._sphere(q, rad)
        best = [float("inf"), -1]
        unsigned = fcl.DistanceRequest()
        signed = fcl.DistanceRequest(enable_signed_distance=True)

        def callback(o1: Any, o2: Any, _data: Any) -> tuple[bool, float]:
            res = fcl.DistanceResult()
            # The unsigned query has closed forms for sphere-box (exact); fcl's signed distance goes
            # through GJK/EPA (errors ~1e-5 m), so it is only asked for the penetration depth.
            d = fcl.distance(o1, o2, unsigned, res)
            if d <= 0:
                res = fcl.DistanceResult()
                d = fcl.distance(o1, o2, signed, res)
            i = self._obstacle_index(res.o1, res.o2)
            if d < 0 and self._surface[i]:
                # fcl flags a mesh contact with -1 (not a depth); all we know is "touching".
                d = 0.0
            if d < best[0]:
                best[0], best[1] = float(d), i
            return False, best[0]

        self._manager.distance(query, None, callback)
        return best[0], self.names[best[1]]

    def clearance(self, p: np.ndarray, r: float) -> float:
        """Distance (m) from the ball of radius ``r`` at ``p`` to the nearest obstacle.

        Positive when free (exact). On contact it is ``<= 0``: minus the penetration depth for
        boxes and convex meshes, ``0`` for non-convex meshes (fcl reports no depth for them).
        ``inf`` in an empty world.
        """
        return self.nearest(p, r)[0]

    def clearances(self, path: np.ndarray, r: float) -> np.ndarray:
        """:meth:`clearance` at every sample of ``path`` : (T, 3) float; returns (T,) float."""
        pts = _check_path(path)
        return np.array([self.clearance(p, r) for p in pts])

    def first_contact(self, path: np.ndarray, r: float) -> int | None:
        """Index of the first sample of a realised ``path`` whose motion touched an obstacle.

        Sample 0 is checked as a ball; sample ``i > 0`` is reported when the capsule swept from
        ``path[i - 1]`` to ``path[i]`` touches. ``None`` when the whole path is free. Use
        :meth:`contact_obstacles` on that segment for the names.

        Parameters
        ----------
        path : (T, 3) float
            Body centre positions at consecutive simulation steps.
        r : float
            Body radius (m).
        """
        pts, rad = _check_path(path), _check_radius(r)
        if self.empty or len(pts) == 0:
            return None
        if self._collides(self._sphere(pts[0], rad)):
            return 0
        for i in range(1, len(pts)):
            if self._collides(self._swept(pts[i - 1], pts[i], rad)):
                return i
        return None


def _check_path(path: object) -> np.ndarray:
    pts = np.asarray(path, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise GeometryError(f"path: expected shape (T, 3), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise GeometryError("path: contains NaN or inf")
    return pts
