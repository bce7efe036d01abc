"""Server maps given as files: OctoMaps, point clouds and meshes, read and turned into voxels.

- **OctoMap** (``.bt``, ``.ot``, any tree type OctoMap reads): its occupied and free leaves.
- **Point cloud** (``.ply``, ``.pcd``, ``.xyz`` through Open3D's reader): with a sensor ``origin``,
  each point is a ray end inserted with OctoMap's ``insertPointCloud`` semantics (free voxels
  along the ray, the end voxel occupied, per-scan update sets); without one, each point only marks
  its voxel occupied and no free space is claimed (a ray from a guessed origin would claim free
  space nobody saw).
- **Mesh** (``.obj``, ``.stl``, ``.ply``, ``.off``, ``.glb``, any format trimesh loads as
  triangles; need not be closed): its surface voxelised at the map's resolution, i.e. every voxel
  whose centre lies within half a voxel diagonal of a triangle (every voxel the surface touches).
  Nothing is claimed free.

Each becomes the claim layer of the robot's map exactly like a claimed OctoMap
(:func:`secure3d.world.attacks.belief_map`), so trust layers, certificate and replay treat them
alike. Errors are :class:`~secure3d.errors.ScenarioError` naming the field and file.
"""

from __future__ import annotations

import io
import math
import os
from pathlib import Path

import numpy as np

from secure3d.errors import ScenarioError

CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz")
SERVER_MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf")
#: Largest point-cloud or mesh file read (bytes).
MAX_SOURCE_BYTES = 200_000_000
#: Most points of a cloud (~10 s of insertion); more is a unit or sampling mistake.
MAX_CLOUD_POINTS = 20_000_000
#: Most triangles of a server mesh.
MAX_SERVER_MESH_FACES = 2_000_000
#: Most candidate voxels the mesh voxeliser examines (bounding box of the mesh at the resolution).
MAX_MESH_CELLS = 50_000_000


def _size_checked(path: Path, what: str, suffixes: tuple[str, ...], kind: str) -> None:
    if path.suffix.lower() not in suffixes:
        raise ScenarioError(
            f"{what}: {kind} files must be {', '.join(suffixes)} (got {path.name!r})"
        )
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise ScenarioError(f"{what}: cannot read {path}: {exc.strerror or exc}") from None
    if size > MAX_SOURCE_BYTES:
        raise ScenarioError(
            f"{what}: {path} is larger than {MAX_SOURCE_BYTES // 1_000_000} MB (got {size} bytes)"
        )


def read_cloud(path: str | os.PathLike[str], what: str = "cloud") -> np.ndarray:
    """Points of a ``.ply``/``.pcd``/``.xyz`` file, through Open3D.

    Returns
    -------
    (n, 3) float64
        Finite points only (Open3D drops NaN points).

    Raises
    ------
    ScenarioError
        Wrong suffix, too large, unreadable, empty, or non-finite points.
    """
    from secure3d._deps import open3d

    p = Path(path)
    _size_checked(p, what, CLOUD_SUFFIXES, "point-cloud")
    o3d = open3d()
    pcd = o3d.io.read_point_cloud(str(p), format="auto", remove_nan_points=True)
    pts = np.asarray(pcd.points, dtype=np.float64)
    if pts.shape[0] == 0:
        raise ScenarioError(f"{what}: {p} holds no points (unreadable or empty)")
    if pts.shape[0] > MAX_CLOUD_POINTS:
        raise ScenarioError(f"{what}: {p} has more than {MAX_CLOUD_POINTS} points")
    if not np.all(np.isfinite(pts)):
        raise ScenarioError(f"{what}: {p} has non-finite points")
    return pts


def read_surface_mesh(
    path: str | os.PathLike[str], what: str = "mesh"
) -> tuple[np.ndarray, np.ndarray]:
    """Triangles of any mesh file trimesh reads (open surfaces allowed).

    Returns
    -------
    vertices : (v, 3) float64
    faces : (f, 3) int64

    Raises
    ------
    ScenarioError
        Wrong suffix, too large, unparsable, empty, or non-finite vertices.
    """
    import trimesh

    p = Path(path)
    _size_checked(p, what, SERVER_MESH_SUFFIXES, "mesh")
    try:
        mesh = trimesh.load(
            io.BytesIO(p.read_bytes()), file_type=p.suffix[1:].lower(), force="mesh", resolver=None
        )
    except Exception as exc:  # noqa: BLE001 - any parser failure means a broken file
        detail = " ".join(str(exc).split())[:120] or type(exc).__name__
        raise ScenarioError(f"{what}: cannot parse {p}: {detail}") from None
    v = np.asarray(getattr(mesh, "vertices", np.empty((0, 3))), dtype=np.float64)
    f = np.asarray(getattr(mesh, "faces", np.empty((0, 3))), dtype=np.int64)
    if f.ndim != 2 or f.shape[0] == 0 or f.shape[1] != 3:
        raise ScenarioError(f"{what}: {p} holds no triangles")
    if f.shape[0] > MAX_SERVER_MESH_FACES:
        raise ScenarioError(f"{what}: {p} has more than {MAX_SERVER_MESH_FACES} triangles")
    if not np.all(np.isfinite(v)):
        raise ScenarioError(f"{what}: {p} has non-finite vertices")
    return v, f


def surface_voxel_centres(
    vertices: np.ndarray, faces: np.ndarray, resolution: float, what: str = "mesh"
) -> np.ndarray:
    """Centres of every voxel of the OctoMap grid that the surface touches.

    A voxel is taken when its centre lies within half a voxel diagonal of a triangle (Open3D's
    unsigned distance), which includes every voxel a triangle passes through.

    Parameters
    ----------
    vertices : (v, 3) float
    faces : (f, 3) int
    resolution : float

    Returns
    -------
    (n, 3) float64
    """
    from secure3d._deps import open3d

    half_diag = 0.5 * math.sqrt(3.0) * resolution
    klo = np.floor((vertices.min(axis=0) - half_diag) / resolution).astype(np.int64)
    khi = np.floor((vertices.max(axis=0) + half_diag) / resolution).astype(np.int64)
    shape = khi - klo + 1
    if float(np.prod(shape.astype(float))) > MAX_MESH_CELLS:
        raise ScenarioError(
            f"{what}: voxelising at {resolution:g} m would examine {np.prod(shape):.3g} cells"
            f" (limit {MAX_MESH_CELLS:.0e}); check units or resolution"
        )
    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(vertices.astype(np.float32)), o3d.core.Tensor(faces.astype(np.uint32))
    )
    out = []
    ix, iy, iz = (np.arange(n) for n in shape)
    for x0 in range(0, int(shape[0]), 64):  # slabs: bounded memory
        g = np.stack(np.meshgrid(ix[x0 : x0 + 64], iy, iz, indexing="ij"), -1).reshape(-1, 3)
        centres = (g + klo + 0.5) * resolution
        d = scene.compute_distance(o3d.core.Tensor(centres.astype(np.float32))).numpy()
        out.append(centres[d <= half_diag])
    return np.concatenate(out)


def check_source_file(path: Path, field: str, what: str) -> float | None:
    """Read a server-map file once at load time so that a broken file fails there.

    Returns the file's own resolution for an OctoMap (to compare with
    ``server_map.resolution``), else None.
    """
    if field == "bt":
        from secure3d.world.attacks import octomap_resolution

        return octomap_resolution(path, what)
    if field == "cloud":
        read_cloud(path, what)
    else:
        read_surface_mesh(path, what)
    return None


__all__ = [
    "CLOUD_SUFFIXES",
    "SERVER_MESH_SUFFIXES",
    "check_source_file",
    "read_cloud",
    "read_surface_mesh",
    "surface_voxel_centres",
]
