"""A pinhole depth camera ray-cast against the true world with Open3D.

The camera renders what the robot's sensor would return (paper eq. SensorModel): a z-depth image
of the first surface along every pixel ray, so occlusion is real. The Open3D scene is built once
per world; a frame costs one ``cast_rays`` call.

Conventions (shared with :meth:`secure3d.mapping.occupancy.OccupancyMap.insert_depth_image`):

- optical frame: z forward, x right, y down; ``R_world_from_optical`` maps optical to world;
- pixel ``(u, v)`` (column, row) has its centre at ``((u + 0.5 - cx) / fx, (v + 0.5 - cy) / fy, 1)``
  times the depth, with ``cx = width / 2`` and ``cy = height / 2``: exactly the rays of Open3D's
  ``RaycastingScene.create_rays_pinhole``;
- ``depth`` is z-depth (m). ``inf`` means "no surface within range" (the ray is free up to the
  range limit); ``NaN`` means "no data" (dropout): a map update must skip such pixels.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

from secure3d._deps import open3d as _open3d
from secure3d.errors import ConfigError, GeometryError
from secure3d.simulation.scene import labelled_union
from secure3d.world.spec import CameraSpec

#: Label of pixels that hit nothing (or whose hit was beyond range or dropped).
NO_HIT = -1


def _check_pose(R_world_from_optical: object, origin: object) -> tuple[np.ndarray, np.ndarray]:
    R = np.asarray(R_world_from_optical, dtype=float)
    o = np.asarray(origin, dtype=float)
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise GeometryError(f"R_world_from_optical: expected a finite (3, 3) array, got {R.shape}")
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
        raise GeometryError("R_world_from_optical: not a rotation matrix (R^T R != I or det < 0)")
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise GeometryError(f"origin: expected 3 finite numbers, got {origin!r}")
    return R, o


@dataclass(frozen=True, eq=False)
class DepthFrame:
    """One rendered depth image and everything needed to use it.

    Attributes
    ----------
    depth : (H, W) float32
        z-depth (m); ``inf`` = nothing within ``max_range``; ``NaN`` = dropped pixel (no data).
    fx, fy, cx, cy : float
        Pinhole intrinsics (pixels); pixel centres at ``u + 0.5``, ``v + 0.5``.
    rotation : (3, 3) float
        ``R_world_from_optical`` at capture.
    origin : (3,) float
        Camera centre in the world (m).
    max_range : float
        Range limit (m) of the sensor; ``far_kind`` says whether it limits z-depth or range.
    far_kind : str
        ``"depth"`` or ``"range"``.
    hit_ids : (H, W) int32
        Index into ``names`` of the obstacle each valid pixel hit, :data:`NO_HIT` elsewhere.
    names : tuple of str
        Obstacle names (``world_trimesh``'s ``metadata["obstacle_names"]``).
    """

    depth: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    rotation: np.ndarray
    origin: np.ndarray
    max_range: float
    far_kind: str
    hit_ids: np.ndarray
    names: tuple[str, ...]

    @property
    def width(self) -> int:
        return int(self.depth.shape[1])

    @property
    def height(self) -> int:
        return int(self.depth.shape[0])

    def rays_optical(self) -> np.ndarray:
        """Per-pixel ray directions in the optical frame with unit z, (H, W, 3) float."""
        return pixel_rays(self.width, self.height, self.fx, self.fy, self.cx, self.cy)

    def points_optical(self) -> np.ndarray:
        """Hit points of the valid (finite) pixels in the optical frame, (n, 3) float, row-major."""
        valid = np.isfinite(self.depth)
        return self.rays_optical()[valid] * self.depth[valid, None].astype(float)

    def points_world(self) -> np.ndarray:
        """Hit points of the valid (finite) pixels in the world frame, (n, 3) float, row-major."""
        return self.points_optical() @ self.rotation.T + self.origin

    def hit_names(self) -> frozenset[str]:
        """Names of the obstacles at least one valid pixel of this frame saw."""
        ids = self.hit_ids[self.hit_ids != NO_HIT]
        seen = np.flatnonzero(np.bincount(ids, minlength=len(self.names)))
        return frozenset(self.names[i] for i in seen)

    def hit_counts(self) -> dict[str, int]:
        """Number of valid pixels that saw each obstacle (only obstacles that were seen)."""
        ids, counts = np.unique(self.hit_ids[self.hit_ids != NO_HIT], return_counts=True)
        return {self.names[i]: int(c) for i, c in zip(ids, counts, strict=True)}


def intrinsics(spec: CameraSpec) -> tuple[float, float, float, float]:
    """``(fx, fy, cx, cy)`` of ``spec`` (pixels), principal point at the image centre."""
    return spec.fx, spec.fy, spec.width / 2.0, spec.height / 2.0


def pixel_rays(width: int, height: int, fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    """Optical-frame ray of every pixel centre, scaled to unit z: (H, W, 3) float.

    ``t`` along such a ray *is* the z-depth, which is what Open3D's ``t_hit`` returns for the rays
    of ``create_rays_pinhole`` (DESIGN.md section 5).
    """
    u = (np.arange(width) + 0.5 - cx) / fx
    v = (np.arange(height) + 0.5 - cy) / fy
    uu, vv = np.meshgrid(u, v)
    return np.stack([uu, vv, np.ones_like(uu)], axis=-1)


class DepthCamera:
    """Ray-casts depth frames of the true world (paper eq. SensorModel, with occlusion).

    Parameters
    ----------
    camera_spec : CameraSpec
        Resolution, field of view, range limit and its kind, noise and dropout.
    mesh : trimesh.Trimesh or sequence of (name, trimesh.Trimesh)
        The world. A labelled mesh from :func:`~secure3d.simulation.scene.world_trimesh` (or a list
        from :func:`~secure3d.simulation.scene.obstacle_meshes`) lets frames report which obstacle
        each pixel hit; an unlabelled mesh is reported as one obstacle named ``"world"``.
    rng : numpy.random.Generator or int, optional
        Source of depth noise and dropout (``np.random.default_rng(rng)``); pass a seeded generator
        for reproducible runs.
    """

    def __init__(
        self,
        camera_spec: CameraSpec,
        mesh: trimesh.Trimesh | Sequence[tuple[str, trimesh.Trimesh]],
        rng: np.random.Generator | int | None = None,
    ) -> None:
        if not isinstance(camera_spec, CameraSpec):
            kind = type(camera_spec).__name__
            raise ConfigError(f"camera_spec: expected a CameraSpec, got {kind}")
        self.spec = camera_spec
        self.rng = np.random.default_rng(rng)
        if not isinstance(mesh, trimesh.Trimesh):
            mesh = labelled_union(mesh)
        vertices = np.asarray(mesh.vertices, dtype=np.float32)
        faces = np.asarray(mesh.faces, dtype=np.uint32)
        if len(faces) and not np.all(np.isfinite(vertices)):
            raise GeometryError("mesh: vertices contain NaN or inf")
        labels = mesh.face_attributes.get("obstacle") if mesh.face_attributes else None
        names = mesh.metadata.get("obstacle_names") if mesh.metadata else None
        if labels is None or names is None or len(labels) != len(faces):
            labels, names = np.zeros(len(faces), dtype=np.int32), ("world",)
        self.names: tuple[str, ...] = tuple(names)
        self._face_label = np.asarray(labels, dtype=np.int32)

        o3d = _open3d()
        self._o3d = o3d
        self._scene = o3d.t.geometry.RaycastingScene()
        if len(faces):
            self._scene.add_triangles(o3d.core.Tensor(vertices), o3d.core.Tensor(faces))
            # Embree builds the scene's BVH on the first query: 0.28-0.37 s for a laser-scanned
            # office (geb079's voxels), which would land in the first frame of the flight. One
            # ray here builds it with the world, in the set-up.
            self._scene.cast_rays(o3d.core.Tensor(np.array([[0, 0, 0, 0, 0, 1]], np.float32)))
        self.fx, self.fy, self.cx, self.cy = intrinsics(camera_spec)
        self._K = o3d.core.Tensor(self.intrinsic_matrix)
        rays = pixel_rays(camera_spec.width, camera_spec.height, self.fx, self.fy, self.cx, self.cy)
        # Euclidean length of each unit-z ray: range = depth * this (for far_kind "range").
        self._ray_norm = np.linalg.norm(rays, axis=-1).astype(np.float32)

    @property
    def intrinsic_matrix(self) -> np.ndarray:
        """The 3x3 pinhole matrix K (pixels)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def render(self, R_world_from_optical: np.ndarray, origin: np.ndarray) -> DepthFrame:
        """Ray-cast one depth frame from the camera pose.

        Parameters
        ----------
        R_world_from_optical : (3, 3) float
            Camera orientation (optical frame: z forward, x right, y down).
        origin : (3,) float
            Camera centre in the world (m).

        Returns
        -------
        DepthFrame
            ``depth`` (H, W) float32 z-depth with ``inf`` beyond range or without a hit, Gaussian
            noise of ``noise_std`` on valid pixels and a ``dropout`` fraction of pixels set to NaN.
        """
        R, o = _check_pose(R_world_from_optical, origin)
        spec = self.spec
        world_to_camera = np.eye(4)
        world_to_camera[:3, :3] = R.T
        world_to_camera[:3, 3] = -R.T @ o
        core = self._o3d.core
        rays = self._o3d.t.geometry.RaycastingScene.create_rays_pinhole(
            self._K, core.Tensor(world_to_camera), spec.width, spec.height
        )
        hit = self._scene.cast_rays(rays)
        depth = hit["t_hit"].numpy()
        limit = depth if spec.far_kind == "depth" else depth * self._ray_norm
        depth = np.where(limit <= spec.max_range, depth, np.float32(np.inf))
        seen = np.isfinite(depth)
        prim = hit["primitive_ids"].numpy()
        ids = np.full(depth.shape, NO_HIT, dtype=np.int32)
        ids[seen] = self._face_label[prim[seen]]

        if spec.noise_std > 0:
            noise = self.rng.normal(0.0, spec.noise_std, size=depth.shape).astype(np.float32)
            # A noisy reading stays in front of the camera and within the sensor's range.
            depth = np.where(seen, np.clip(depth + noise, 1e-3, None), depth)
            limit = depth if spec.far_kind == "depth" else depth * self._ray_norm
            depth = np.where(seen & (limit > spec.max_range), np.float32(np.inf), depth)
            seen = np.isfinite(depth)
            ids[~seen] = NO_HIT
        if spec.dropout > 0:
            dropped = self.rng.random(depth.shape) < spec.dropout
            depth = np.where(dropped, np.float32(np.nan), depth)
            ids[dropped] = NO_HIT

        return DepthFrame(
            depth=depth.astype(np.float32, copy=False),
            fx=self.fx,
            fy=self.fy,
            cx=self.cx,
            cy=self.cy,
            rotation=R.copy(),
            origin=o.copy(),
            max_range=spec.max_range,
            far_kind=spec.far_kind,
            hit_ids=ids,
            names=self.names,
        )
