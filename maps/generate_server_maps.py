"""Regenerate the file server maps of cloud_server.yaml, mesh_server.yaml and warehouse_survey.yaml.

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

``clouds/warehouse_survey.graph`` is an OctoMap scan graph (the ``.graph`` of OctoMap's tools) of
the warehouse of warehouse_survey.yaml surveyed *before* the barrel was put in aisle C and while shelf_3
stood 0.6 m further north: four scans of a rotating lidar (360 degrees in azimuth every 0.6
degrees, +-24 degrees in elevation every 2 degrees, 20 m range) at four poses, each yawed and
tilted, its points in the sensor's frame as such files hold them.

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


SURVEY_POSES = (  # (x, y, z), (roll, pitch, yaw) in degrees
    ((1.5, 6.9, 1.0), (0.0, 0.0, 0.0)),
    ((8.0, 6.9, 1.2), (2.0, 6.0, 90.0)),
    ((14.8, 6.0, 1.0), (0.0, -4.0, 180.0)),
    ((8.0, 3.9, 1.2), (-3.0, 0.0, -90.0)),
)


def survey_mesh() -> trimesh.Trimesh:
    from secure3d.world import load_scenario

    world = load_scenario(HERE / "warehouse_survey.yaml").world
    parts = []
    for b in world.boxes:
        lo, hi = np.array(b.lo), np.array(b.hi)
        if b.name == "shelf_3":  # where it stood when the survey was made
            lo, hi = lo + [0.0, 0.6, 0.0], hi + [0.0, 0.6, 0.0]
        box = trimesh.creation.box(extents=hi - lo)
        box.apply_translation(0.5 * (lo + hi))
        parts.append(box)
    parts += [trimesh.Trimesh(m.vertices, m.faces) for m in world.meshes if m.name != "barrel"]
    return trimesh.util.concatenate(parts)


def survey_poses() -> list[tuple[np.ndarray, np.ndarray]]:
    from secure3d.mapping.scan_graph import euler_quaternion

    return [(np.array(t, float), euler_quaternion(*np.radians(rpy))) for t, rpy in SURVEY_POSES]


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
    from secure3d.mapping.scan_graph import write_scan_graph_bytes
    from secure3d.world.survey_families import survey_scans

    mesh = survey_mesh()
    scans = survey_scans(mesh.vertices, mesh.faces, survey_poses(), 24.0, azimuth_step_deg=0.6)
    graph = HERE / "clouds" / "warehouse_survey.graph"
    graph.write_bytes(write_scan_graph_bytes(scans))
    print(f"{graph}: {len(scans)} scans, {sum(len(s[0]) for s in scans)} points")


if __name__ == "__main__":
    main()
