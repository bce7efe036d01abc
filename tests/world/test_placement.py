"""Start and goal must be clear of meshes and OctoMap voxels; simulation settings are bounded."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest

from secure3d.errors import ScenarioError
from secure3d.world.attacks import octomap_voxel_boxes
from secure3d.world.meshes import load_mesh, mesh_from_arrays
from secure3d.world.placement import point_mesh_distance, winding_number
from secure3d.world.scenario import load_scenario


def _edited(maps_dir, tmp_path, name, pattern, replacement):
    text = (maps_dir / name).read_text()
    new, n = re.subn(pattern, replacement, text, count=1)
    assert n == 1, pattern
    for sub in ("meshes", "octomaps"):
        if (maps_dir / sub).is_dir() and not (tmp_path / sub).exists():
            shutil.copytree(maps_dir / sub, tmp_path / sub)
    path = tmp_path / name
    path.write_text(new)
    return path


def test_a_start_inside_a_tree_mesh_is_refused(maps_dir, tmp_path):
    path = _edited(
        maps_dir,
        tmp_path,
        "forest.yaml",
        r"start: \{position: \[[^\]]*\]",
        "start: {position: [3.08, 2.70, 1.0]",
    )
    with pytest.raises(ScenarioError, match=r"start.position: the body .* overlaps mesh 'tree_00'"):
        load_scenario(path)


def test_a_goal_inside_an_octomap_voxel_is_refused(maps_dir, tmp_path):
    scenario = load_scenario(maps_dir / "office_bt.yaml")
    boxes = octomap_voxel_boxes(scenario.world.octomap)
    b = scenario.world.bounds
    centres = boxes.mean(axis=1)
    r = scenario.vehicle.body_radius
    ok = np.all(centres > np.array(b.lo) + r + 0.05, axis=1) & np.all(
        centres < np.array(b.hi) - r - 0.05, axis=1
    )
    c = centres[np.flatnonzero(ok)[len(np.flatnonzero(ok)) // 2]]
    goal = ", ".join(f"{x:.4f}" for x in c)
    path = _edited(
        maps_dir,
        tmp_path,
        "office_bt.yaml",
        r"goal: \{position: \[[^\]]*\]",
        f"goal: {{position: [{goal}]",
    )
    with pytest.raises(ScenarioError, match="goal.position: .* occupied voxel of world.octomap"):
        load_scenario(path)


def test_winding_number_and_distance_of_a_unit_cube():
    import trimesh

    cube = trimesh.creation.box(extents=(1, 1, 1))
    v, f = np.asarray(cube.vertices), np.asarray(cube.faces)
    assert winding_number(np.zeros(3), v, f) == pytest.approx(1.0, abs=1e-9)
    assert winding_number(np.array([2.0, 0, 0]), v, f) == pytest.approx(0.0, abs=1e-9)
    assert point_mesh_distance(np.array([2.0, 0, 0]), v, f) == pytest.approx(1.5)
    assert point_mesh_distance(np.array([0.2, 0, 0]), v, f) == pytest.approx(0.3)


def test_nan_mesh_vertices_are_named_as_such(tmp_path):
    with pytest.raises(ScenarioError, match="NaN or infinite"):
        mesh_from_arrays(
            [[0, 0, 0], [1, 0, 0], [0, np.nan, 0], [0, 0, 1]],
            [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
            "bad",
        )
    obj = tmp_path / "bad.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 nan 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    with pytest.raises(ScenarioError, match="1 vertices with NaN or infinite coordinates"):
        load_mesh(obj, "bad")


@pytest.mark.parametrize(
    ("sim", "message"),
    [
        ("{dt: 1.0e-9}", r"simulation.dt: must be in \[0.0001, 0.1\]"),
        ("{dt: 0.001, time_limit: 1000}", "at most 200000 steps"),
    ],
)
def test_simulation_steps_are_bounded(maps_dir, tmp_path, sim, message):
    text = (maps_dir / "blind_corner.yaml").read_text()
    assert "\nsimulation:" in text
    text = re.sub(r"\nsimulation:[^\n]*", f"\nsimulation: {sim}", text, count=1)
    path = tmp_path / "sim.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=message):
        load_scenario(path)
