"""Regenerate the point-cloud and mesh server maps of cloud_server.yaml and mesh_server.yaml.

Run from the repository root::

    .venv/bin/python maps/generate_server_maps.py

Both scenarios are the blind corner (blind_corner.yaml) with the server map given as a file made
*before the crate was put there*, so the file lacks it, like a map server that is out of date:

- ``clouds/blind_corner_scan.ply``: a synthetic lidar scan taken from the corridor's elbow
  (6.75, 1.25, 1.25), which sees down both legs: rays every 0.6 degrees in azimuth and elevation
  cast against the world's boxes minus the crate (Open3D ray casting), hits within 12 m kept,
  float32 binary PLY;
- ``meshes/blind_corner_building.obj``: the building's surfaces, every box minus the crate as a
  box mesh (open surfaces are fine for a server mesh).

Everything is deterministic; the committed files are the output of this script.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh
import yaml

from secure3d._deps import open3d

o3d = open3d()

HERE = Path(__file__).resolve().parent
SCAN_ORIGIN = np.array([6.75, 1.25, 1.25])
STEP_DEG = 0.6
MAX_RANGE = 12.0


def building_boxes() -> list[tuple[np.ndarray, np.ndarray]]:
    data = yaml.safe_load((HERE / "blind_corner.yaml").read_text())
    return [
        (np.array(b["lo"], float), np.array(b["hi"], float))
        for b in data["world"]["boxes"]
        if b["name"] != "crate"
    ]


def building_mesh() -> trimesh.Trimesh:
    parts = []
    for lo, hi in building_boxes():
        box = trimesh.creation.box(extents=hi - lo)
        box.apply_translation(0.5 * (lo + hi))
        parts.append(box)
    return trimesh.util.concatenate(parts)


def scan(mesh: trimesh.Trimesh) -> np.ndarray:
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
        o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)),
    )
    az = np.radians(np.arange(-180.0, 180.0, STEP_DEG))
    el = np.radians(np.arange(-89.7, 90.0, STEP_DEG))
    a, e = np.meshgrid(az, el, indexing="ij")
    d = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    rays = np.concatenate([np.broadcast_to(SCAN_ORIGIN, d.shape), d], axis=1).astype(np.float32)
    t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    hit = np.isfinite(t) & (t <= MAX_RANGE)
    return (SCAN_ORIGIN + d[hit] * t[hit, None]).astype(np.float32)


def main() -> None:
    mesh = building_mesh()
    (HERE / "meshes").mkdir(exist_ok=True)
    mesh.export(HERE / "meshes" / "blind_corner_building.obj")
    points = scan(mesh)
    pcd = o3d.t.geometry.PointCloud(o3d.core.Tensor(points))
    (HERE / "clouds").mkdir(exist_ok=True)
    out = HERE / "clouds" / "blind_corner_scan.ply"
    o3d.t.io.write_point_cloud(str(out), pcd, write_ascii=False)
    print(f"{out}: {len(points)} points; meshes/blind_corner_building.obj: {len(mesh.faces)} faces")


if __name__ == "__main__":
    main()
