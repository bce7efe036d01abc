"""``secure3d map``: look into and convert the maps users bring.

- ``secure3d map info FILE``: an OctoMap (``.bt``/``.ot``, any tree type OctoMap reads), a point
  cloud (``.ply``/``.pcd``/``.xyz``, or OctoMap's point file ``.dat``/``.dat.bz2``), an OctoMap
  scan graph (``.graph``/``.log``) or a mesh: its
  type, resolution, leaves, scans, bounds, occupied volume, and whether it has colours.
- ``secure3d map convert IN OUT``: a cloud or scan graph (``--resolution``; OctoMap rays from each
  scan's pose, its per-point origins or ``--origin``, else its points only; a scan graph as
  ``graph2tree`` builds it), a mesh (``--resolution``; its surface voxelised) or an OctoMap to
  ``.bt``/``.ot``; an OctoMap back to a point cloud of its occupied voxel centres (in its colours
  for a colour tree).

Errors are one line (``secure3d: error: ...``, exit status 2), like every other command.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from secure3d.errors import ConfigError, MapFormatError


def map_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``info`` and ``convert`` to the ``map`` command's parser."""
    sub = parser.add_subparsers(dest="map_command", metavar="ACTION", required=True)
    info = sub.add_parser(
        "info", help="describe a map file (OctoMap, point cloud, scan graph or mesh)"
    )
    info.add_argument("file", type=Path)
    conv = sub.add_parser(
        "convert", help="convert a cloud, scan graph, mesh or OctoMap to .bt/.ot, or back"
    )
    conv.add_argument("input", type=Path)
    conv.add_argument("output", type=Path, help=".bt, .ot, or .ply/.pcd/.xyz (occupied voxels)")
    conv.add_argument(
        "--resolution", type=float, help="voxel size (m) for a cloud, scan graph or mesh input"
    )
    conv.add_argument(
        "--origin", type=float, nargs=3, metavar=("X", "Y", "Z"), help="sensor origin of a cloud"
    )


def run_map(args: argparse.Namespace) -> int:
    """Run ``secure3d map info|convert``."""
    if args.map_command == "info":
        for line in map_info(args.file):
            print(line)
        return 0
    print(convert(args.input, args.output, args.resolution, args.origin))
    return 0


def _octomap_leaves(path: Path):  # noqa: ANN202
    from secure3d.mapping.octomap_io import read_octomap_file

    try:
        return read_octomap_file(path)
    except OSError as exc:
        raise MapFormatError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except MapFormatError as exc:
        raise MapFormatError(f"{path}: {exc}") from None


def _occupied(leaves) -> np.ndarray:  # noqa: ANN001
    return leaves.values >= 0  # OctoMap's threshold (a .bt's +1/-1 alike)


def map_info(path: Path) -> list[str]:
    """Lines describing the map file ``path``."""
    from secure3d.mapping.keys import TREE_DEPTH, TREE_MAX_VAL, morton_decode

    kind = map_kind(path)
    if kind == "octomap":
        lv = _octomap_leaves(path)
        occ = _occupied(lv)
        span = 2.0 ** (TREE_DEPTH - lv.depths.astype(np.int64))
        voxels = int(np.sum(span[occ] ** 3))
        lines = [
            f"{path}: OctoMap {lv.fmt} file, tree type {lv.tree_id}",
            f"  resolution : {lv.resolution:g} m",
            f"  leaves     : {lv.starts.size} ({int(occ.sum())} occupied, {int((~occ).sum())}"
            " free)",
            f"  occupied   : {voxels} voxels, {voxels * lv.resolution**3:.6g} m^3",
            f"  colour     : {'yes' if lv.colors is not None else 'no'}",
        ]
        if occ.any():
            lo = (morton_decode(lv.starts[occ]) - TREE_MAX_VAL) * lv.resolution
            hi = lo + (span[occ] * lv.resolution)[:, None]
            lines.insert(3, f"  bounds     : {_v(lo.min(0))} - {_v(hi.max(0))} m (occupied)")
        return lines
    from secure3d.world.server_sources import read_cloud, read_cloud_scans, read_surface_mesh

    if kind == "scan graph":
        scans = read_cloud_scans(path, str(path))
        pts, o = scans.points, scans.origins
        return [
            f"{path}: OctoMap scan graph, {len(o)} scans, {len(pts)} points",
            f"  bounds     : {_v(pts.min(0))} - {_v(pts.max(0))} m (points)",
            f"  origins    : {_v(o.min(0))} - {_v(o.max(0))} m (sensor positions)",
        ]
    if kind == "point cloud":
        pts = read_cloud(path, str(path))
        return [
            f"{path}: point cloud, {len(pts)} points",
            f"  bounds     : {_v(pts.min(0))} - {_v(pts.max(0))} m",
        ]
    v, f = read_surface_mesh(path, str(path))
    return [
        f"{path}: mesh, {len(v)} vertices, {len(f)} triangles",
        f"  bounds     : {_v(v.min(0))} - {_v(v.max(0))} m",
    ]


def map_kind(path: Path) -> str:
    """``"octomap"``, ``"scan graph"``, ``"point cloud"`` or ``"mesh"``, by the file's suffix (a
    ``.ply`` by whether it has faces).

    Raises
    ------
    ConfigError
        A suffix no reader takes, naming the file and every format that is read.
    """
    # here, not at the top: `secure3d --help` must not import secure3d.world (casadi, open3d)
    from secure3d.world.map_formats import (
        CLOUD_SUFFIXES,
        GRAPH_SUFFIXES,
        OCTOMAP_SUFFIXES,
        SERVER_MESH_SUFFIXES,
        file_format,
    )

    fmt = file_format(path)
    if fmt in OCTOMAP_SUFFIXES:
        return "octomap"
    if fmt in GRAPH_SUFFIXES:
        return "scan graph"
    if fmt in CLOUD_SUFFIXES and fmt != ".ply" or _is_cloud_ply(path):
        return "point cloud"
    if fmt in SERVER_MESH_SUFFIXES:
        return "mesh"
    clouds = [f for f in CLOUD_SUFFIXES if f not in GRAPH_SUFFIXES]
    raise ConfigError(
        f"{path}: unknown map file type {fmt or '(no suffix)'!r}; secure3d reads OctoMaps"
        f" ({', '.join(OCTOMAP_SUFFIXES)}), point clouds ({', '.join(clouds)}), scan graphs"
        f" ({', '.join(GRAPH_SUFFIXES)}) and meshes ({', '.join(SERVER_MESH_SUFFIXES)})"
    )


def _v(x: np.ndarray) -> str:
    return "(" + ", ".join(f"{float(c):.4g}" for c in x) + ")"


def _is_cloud_ply(path: Path) -> bool:
    """A ``.ply`` without faces is a point cloud."""
    if path.suffix.lower() != ".ply":
        return False
    try:
        with path.open("rb") as fh:
            head = fh.read(4096)
    except OSError as exc:
        raise MapFormatError(f"{path}: cannot read: {exc.strerror or exc}") from None
    header = head.split(b"end_header")[0]
    return b"element face" not in header or b"element face 0" in header


def _leaves_from_points(points: np.ndarray, resolution: float) -> tuple:
    from secure3d.mapping.keys import coords_to_codes, unique_sorted

    codes, valid = coords_to_codes(points, resolution)
    if not valid.all():
        raise ConfigError(f"{int((~valid).sum())} points lie outside OctoMap's key range")
    return unique_sorted(codes)


def convert(src: Path, dst: Path, resolution: float | None, origin: list[float] | None) -> str:
    """Convert ``src`` into ``dst`` (formats by suffix); return a one-line report."""
    from secure3d.mapping import OccupancyMap
    from secure3d.mapping.keys import TREE_DEPTH
    from secure3d.world.map_formats import OCTOMAP_SUFFIXES

    out_suffix = dst.suffix.lower()
    kind = map_kind(src)
    if kind == "octomap":
        if out_suffix in OCTOMAP_SUFFIXES:
            m = OccupancyMap._from_leaves(_octomap_leaves(src), OccupancyMap(0.1).params, None)
            (m.write_bt if out_suffix == ".bt" else m.write_ot)(dst)
            return f"wrote {dst}"
        return _octomap_to_cloud(src, dst)
    if out_suffix not in OCTOMAP_SUFFIXES:
        raise ConfigError(
            f"output {dst.name!r}: a cloud, scan graph or mesh converts to .bt or .ot"
        )
    if resolution is None or not 1e-4 <= resolution <= 100:
        raise ConfigError(f"--resolution: a number in [0.0001, 100] m is needed (got {resolution})")
    m = OccupancyMap(resolution)
    if kind in ("point cloud", "scan graph"):
        from secure3d.world.server_sources import insert_cloud, read_cloud_scans

        scans = read_cloud_scans(src, str(src))
        if not insert_cloud(m, scans, origin):
            codes = _leaves_from_points(scans.points, resolution)
            _set_occupied(m, codes, TREE_DEPTH)
    else:
        from secure3d.world.server_sources import read_surface_mesh, surface_voxel_centres

        v, f = read_surface_mesh(src, str(src))
        _set_occupied(
            m, _leaves_from_points(surface_voxel_centres(v, f, resolution), resolution), TREE_DEPTH
        )
    (m.write_bt if out_suffix == ".bt" else m.write_ot)(dst)
    return f"wrote {dst}: {len(m.occupied_voxels())} occupied voxels at {resolution:g} m"


def _set_occupied(m, codes: np.ndarray, depth: int) -> None:  # noqa: ANN001
    """Mark voxels occupied in the sensor layer at OctoMap's value for one hit."""
    m._sensor.set_leaves(
        codes, np.full(codes.size, depth, np.int8), np.full(codes.size, m.params.hit_log)
    )


def _octomap_to_cloud(src: Path, dst: Path) -> str:
    from secure3d._deps import open3d
    from secure3d.mapping.keys import codes_to_coords
    from secure3d.mapping.store import expand_ranges

    if dst.suffix.lower() not in (".ply", ".pcd", ".xyz"):
        raise ConfigError(f"output {dst.name!r}: an OctoMap converts to .bt, .ot, .ply, .pcd, .xyz")
    lv = _octomap_leaves(src)
    occ = _occupied(lv)
    codes, owner = expand_ranges(lv.starts[occ], lv.depths[occ])
    pts = codes_to_coords(codes, lv.resolution)
    o3d = open3d()
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    if lv.colors is not None:
        pcd.colors = o3d.utility.Vector3dVector(lv.colors[occ][owner] / 255.0)
    dst.parent.mkdir(parents=True, exist_ok=True)
    if not o3d.io.write_point_cloud(str(dst), pcd):
        raise MapFormatError(f"{dst}: Open3D could not write it")
    return f"wrote {dst}: {len(pts)} occupied voxel centres" + (
        " with colours" if lv.colors is not None else ""
    )
