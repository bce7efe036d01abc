"""The map files secure3d reads, by suffix: the one place that knows which suffix is which format
(scenarios, :mod:`secure3d.world.server_sources`, :mod:`secure3d.world.octomap_files` and
``secure3d map`` all ask here)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = [
    "CLOUD_SUFFIXES",
    "GRAPH_SUFFIXES",
    "OCTOMAP_SUFFIXES",
    "OPEN3D_CLOUD_SUFFIXES",
    "POINT_FILE_SUFFIXES",
    "SERVER_MESH_SUFFIXES",
    "file_format",
    "not_a_tree",
]

#: OctoMap trees (any tree type OctoMap reads).
OCTOMAP_SUFFIXES = (".bt", ".ot")
#: Scan graphs: scans with poses (read by :mod:`secure3d.mapping.scan_graph`, not Open3D).
GRAPH_SUFFIXES = (".graph", ".log")
#: OctoMap's plain point files (``x y z`` per line), plain or bzip2-compressed.
POINT_FILE_SUFFIXES = (".dat", ".dat.bz2")
#: Clouds Open3D reads.
OPEN3D_CLOUD_SUFFIXES = (".ply", ".pcd", ".xyz")
#: Every point-cloud source of ``server_map.cloud``.
CLOUD_SUFFIXES = (*OPEN3D_CLOUD_SUFFIXES, *POINT_FILE_SUFFIXES, *GRAPH_SUFFIXES)
#: Meshes trimesh reads (a ``.ply`` is a mesh when it has faces, else a cloud).
SERVER_MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf")


def file_format(path: str | os.PathLike[str]) -> str:
    """The format suffix of a map file, lower case: its last suffix, or its last two for a
    compressed file (``scan.dat.bz2`` -> ``.dat.bz2``)."""
    p = Path(path)
    last = p.suffix.lower()
    if last == ".bz2" and len(p.suffixes) >= 2:
        return p.suffixes[-2].lower() + last
    return last


def not_a_tree(path: str | os.PathLike[str]) -> str | None:
    """``"scan graph"`` or ``"point cloud"`` for a map file that is not an OctoMap tree but
    converts to one (``secure3d map convert``), else None (a ``.ply`` may be a mesh: None)."""
    fmt = file_format(path)
    if fmt in GRAPH_SUFFIXES:
        return "scan graph"
    if fmt in CLOUD_SUFFIXES and fmt != ".ply":
        return "point cloud"
    return None
