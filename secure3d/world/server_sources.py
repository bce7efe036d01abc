"""Server maps given as files: OctoMaps, point clouds and meshes, read and turned into voxels.

- **OctoMap** (``.bt``, ``.ot``, any tree type OctoMap reads): its occupied and free leaves.
- **Point cloud** (``.ply``, ``.pcd``, ``.xyz`` through Open3D's reader): each point is a ray
  end inserted with OctoMap's ``insertPointCloud`` semantics (free voxels along the ray, the end
  voxel occupied, per-scan update sets) from its own origin if the file has per-point origins
  (vertex properties ``origin_x``, ``origin_y``, ``origin_z``: one scan per distinct origin),
  else from the scenario's ``origin``; without either, each point only marks its voxel occupied
  and no free space is claimed (a ray from a guessed origin would claim free space nobody saw).
- **OctoMap point file** (``.dat``, or bzip2-compressed ``.dat.bz2``, as OctoMap's own
  ``scan.dat.bz2``): whitespace-separated ``x y z`` per line, read by
  :func:`secure3d.mapping.octomap_io.read_scan_dat`; one scan, from the scenario's ``origin``.
- **OctoMap scan graph** (``.graph``, or its text form ``.log``;
  :mod:`secure3d.mapping.scan_graph`): every scan inserted from its node's pose, in file order,
  as OctoMap's ``graph2tree`` does.
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
from typing import NamedTuple

import numpy as np

from secure3d.errors import MapFormatError, ScenarioError
from secure3d.world.map_formats import (
    CLOUD_SUFFIXES,
    GRAPH_SUFFIXES,
    OPEN3D_CLOUD_SUFFIXES,
    POINT_FILE_SUFFIXES,
    SERVER_MESH_SUFFIXES,
    file_format,
)
from secure3d.world.octomap_files import octomap_resolution

#: Largest point-cloud or mesh file read (bytes).
MAX_SOURCE_BYTES = 200_000_000
#: Most points of a cloud (~10 s of insertion); more is a unit or sampling mistake.
MAX_CLOUD_POINTS = 20_000_000
#: Most distinct per-point sensor origins (scans) of a cloud.
MAX_CLOUD_ORIGINS = 10_000
#: Most triangles of a server mesh.
MAX_SERVER_MESH_FACES = 2_000_000
#: Most candidate voxels the mesh voxeliser examines (bounding box of the mesh at the resolution).
MAX_MESH_CELLS = 50_000_000


def _size_checked(
    path: Path, what: str, suffixes: tuple[str, ...], kind: str, limit: int = 0
) -> None:
    limit = limit or MAX_SOURCE_BYTES
    if file_format(path) not in suffixes:
        raise ScenarioError(
            f"{what}: {kind} files must be {', '.join(suffixes)} (got {path.name!r})"
        )
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise ScenarioError(f"{what}: cannot read {path}: {exc.strerror or exc}") from None
    if size > limit:
        raise ScenarioError(
            f"{what}: {path} is larger than {limit // 1_000_000} MB (got {size} bytes)"
        )


def read_cloud(path: str | os.PathLike[str], what: str = "cloud") -> np.ndarray:
    """Points of a cloud or scan-graph file (see :func:`read_cloud_scans`).

    Returns
    -------
    (n, 3) float64
    """
    return read_cloud_scans(path, what).points


class CloudScans(NamedTuple):
    """A point-cloud file's points grouped into the scans they were taken in.

    Attributes
    ----------
    points : (n, 3) float64
        World-frame points, scan after scan.
    origins : (m, 3) float64 or None
        Each scan's sensor position; None when the file has no origins (one unlocated scan).
    offsets : (m + 1,) int64 or None
        Scan ``i`` is ``points[offsets[i]:offsets[i + 1]]``; None with ``origins``.
    """

    points: np.ndarray
    origins: np.ndarray | None = None
    offsets: np.ndarray | None = None


def read_cloud_scans(path: str | os.PathLike[str], what: str = "cloud") -> CloudScans:
    """A cloud file's points and scans: a scan graph's nodes in file order, a ``.ply``/``.pcd``
    with per-point origins one scan per distinct origin (in order of first appearance), any
    other cloud one scan without an origin.

    Raises
    ------
    ScenarioError
        Wrong suffix, too large, unreadable or malformed (naming ``what`` and the file), empty,
        or too many points or scans.
    """
    p = Path(path)
    if p.suffix.lower() in GRAPH_SUFFIXES:
        return _read_graph_scans(p, what)
    pts, origins = read_cloud_origins(p, what)
    if origins is None:
        return CloudScans(pts)
    uniq, first, inverse = np.unique(origins, axis=0, return_index=True, return_inverse=True)
    if len(uniq) > MAX_CLOUD_ORIGINS:
        raise ScenarioError(
            f"{what}: {len(uniq)} distinct per-point origins, more than {MAX_CLOUD_ORIGINS}"
            " scans (group the points by scan)"
        )
    rank = np.empty(len(uniq), np.int64)
    rank[np.argsort(first)] = np.arange(len(uniq))
    scan_of = rank[inverse.ravel()]
    order = np.argsort(scan_of, kind="stable")
    offsets = np.searchsorted(scan_of[order], np.arange(len(uniq) + 1))
    return CloudScans(pts[order], uniq[np.argsort(first)], offsets.astype(np.int64))


def _read_graph_scans(p: Path, what: str) -> CloudScans:
    from secure3d.mapping.scan_graph import MAX_GRAPH_BYTES, read_scan_graph

    _size_checked(p, what, GRAPH_SUFFIXES, "scan-graph", MAX_GRAPH_BYTES)
    try:
        graph = read_scan_graph(p)
    except OSError as exc:
        raise ScenarioError(f"{what}: cannot read {p}: {exc.strerror or exc}") from None
    except MapFormatError as exc:
        raise ScenarioError(f"{what}: {exc}") from None
    if len(graph.points) > MAX_CLOUD_POINTS:
        raise ScenarioError(f"{what}: {p} has more than {MAX_CLOUD_POINTS} points")
    if len(graph.origins) > MAX_CLOUD_ORIGINS:
        raise ScenarioError(f"{what}: {p} has more than {MAX_CLOUD_ORIGINS} scans")
    return CloudScans(graph.points, graph.origins, graph.offsets)


def read_survey_scans(data: bytes) -> CloudScans:
    """The scans of a scan graph held in memory (``server_map.survey``)."""
    from secure3d.mapping.scan_graph import read_scan_graph_bytes

    try:
        graph = read_scan_graph_bytes(data)
    except MapFormatError as exc:
        raise ScenarioError(f"server_map.survey: {exc}") from None
    return CloudScans(graph.points, graph.origins, graph.offsets)


def read_cloud_origins(
    path: str | os.PathLike[str], what: str = "cloud"
) -> tuple[np.ndarray, np.ndarray | None]:
    """Points of a ``.ply``/``.pcd``/``.xyz`` file or an OctoMap point file (``.dat``,
    ``.dat.bz2``) and, if it has them, their sensor origins.

    Per-point origins are the vertex properties ``origin_x``, ``origin_y``, ``origin_z`` (a
    ``.ply`` or ``.pcd`` with those fields, read through Open3D's tensor API). Rows with a
    non-finite point or origin are dropped.

    Returns
    -------
    points : (n, 3) float64
    origins : (n, 3) float64 or None

    Raises
    ------
    ScenarioError
        Wrong suffix, too large, unreadable, empty, or too many points.
    """
    from secure3d._deps import open3d

    p = Path(path)
    if p.suffix.lower() in GRAPH_SUFFIXES:
        scans = _read_graph_scans(p, what)
        return scans.points, np.repeat(scans.origins, np.diff(scans.offsets), axis=0)
    if file_format(p) in POINT_FILE_SUFFIXES:
        return _finite_rows(_read_point_file(p, what), None, p, what)
    _size_checked(p, what, OPEN3D_CLOUD_SUFFIXES, "point-cloud")
    o3d = open3d()
    try:
        pcd = o3d.t.io.read_point_cloud(str(p))
    except RuntimeError as exc:
        raise ScenarioError(
            f"{what}: cannot read {p}: {' '.join(str(exc).split())[:120]}"
        ) from None
    if "positions" not in pcd.point or pcd.point["positions"].shape[0] == 0:
        raise ScenarioError(f"{what}: {p} holds no points (unreadable or empty)")
    pts = pcd.point["positions"].numpy().astype(np.float64).reshape(-1, 3)
    if pts.shape[0] > MAX_CLOUD_POINTS:
        raise ScenarioError(f"{what}: {p} has more than {MAX_CLOUD_POINTS} points")
    names = ("origin_x", "origin_y", "origin_z")
    origins = None
    if all(n in pcd.point for n in names):
        origins = np.hstack([pcd.point[n].numpy().reshape(-1, 1) for n in names]).astype(float)
    return _finite_rows(pts, origins, p, what)


def _read_point_file(p: Path, what: str) -> np.ndarray:
    """Points (n, 3) of an OctoMap point file (``.dat``, ``.dat.bz2``), checked."""
    from secure3d.mapping.octomap_io import read_scan_dat

    _size_checked(p, what, POINT_FILE_SUFFIXES, "point-cloud")
    try:
        pts = read_scan_dat(p, max_bytes=MAX_SOURCE_BYTES)
    except OSError as exc:  # unreadable, or not bzip2 data behind a .bz2 name
        raise ScenarioError(f"{what}: cannot read {p}: {exc.strerror or exc}") from None
    except EOFError:  # a .bz2 cut short
        raise ScenarioError(f"{what}: {p}: the compressed data ends early (truncated)") from None
    except MapFormatError as exc:
        raise ScenarioError(f"{what}: {exc}") from None
    if pts.shape[0] == 0:
        raise ScenarioError(f"{what}: {p} holds no points (unreadable or empty)")
    if pts.shape[0] > MAX_CLOUD_POINTS:
        raise ScenarioError(f"{what}: {p} has more than {MAX_CLOUD_POINTS} points")
    return pts


def _finite_rows(
    pts: np.ndarray, origins: np.ndarray | None, p: Path, what: str
) -> tuple[np.ndarray, np.ndarray | None]:
    """The rows whose point (and origin, if any) is finite; an error if none is."""
    keep = np.all(np.isfinite(pts), axis=1)
    if origins is not None:
        keep &= np.all(np.isfinite(origins), axis=1)
        origins = origins[keep]
    if not keep.any():
        raise ScenarioError(f"{what}: {p} has no finite points")
    return pts[keep], origins


def insert_cloud(target: object, scans: CloudScans, origin: object) -> bool:
    """Insert a cloud into ``target`` (an OccupancyMap) as OctoMap rays: scan by scan from each
    scan's origin if the file has them, else as one scan from ``origin``. Returns False (nothing
    inserted) when there is no origin at all.
    """
    if scans.origins is None:
        if origin is None:
            return False
        target.insert_point_cloud(scans.points, np.asarray(origin, float), None)
        return True
    for k, o in enumerate(scans.origins):
        target.insert_point_cloud(scans.points[scans.offsets[k] : scans.offsets[k + 1]], o, None)
    return True


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
        return octomap_resolution(path, what)
    if field == "cloud":
        read_cloud(path, what)
    else:
        read_surface_mesh(path, what)
    return None


__all__ = [
    "CLOUD_SUFFIXES",
    "GRAPH_SUFFIXES",
    "CloudScans",
    "POINT_FILE_SUFFIXES",
    "SERVER_MESH_SUFFIXES",
    "check_source_file",
    "file_format",
    "insert_cloud",
    "read_cloud",
    "read_cloud_origins",
    "read_cloud_scans",
    "read_surface_mesh",
    "surface_voxel_centres",
    "read_survey_scans",
]
