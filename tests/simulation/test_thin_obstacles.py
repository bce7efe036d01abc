"""Issue 16's thin-pole scene in closed loop: real camera, map, IPOPT and FCL."""

from __future__ import annotations

import pytest

import secure3d
from secure3d.errors import ScenarioError
from secure3d.simulation.closed_loop import simulate


def test_the_secure_robot_stops_for_a_4cm_pole_that_a_64x48_camera_sees_late(maps_dir):
    """A 4 cm hidden pole, 0.1 m voxels, a 64 x 48 camera, 5 m/s allowed. Before issue 16 the
    secure robot hit it (its voxels were carved free from afar and its first hits did not bring
    them back); with sticky hits and min_obstacle_size 0.04 m it arrives without collision, and the
    baseline, which trusts the server, meets the pole."""
    scenario = secure3d.load_scenario(maps_dir / "thin_pole.yaml")
    assert scenario.planner.min_obstacle_size == 0.04
    secure = simulate(scenario, "secure", seed=0)
    assert not secure.collided, secure.summary()
    assert secure.reached_goal, secure.summary()
    assert all(p.certificate is not None and p.certificate.ok for _, p in secure.plans)
    baseline = simulate(scenario, "baseline", seed=0)
    assert baseline.collided and "pole" in baseline.collision_obstacles, baseline.summary()


def test_the_secure_robot_ducks_under_a_hidden_beam_seen_with_a_30_deg_vertical_view(maps_dir):
    scenario = secure3d.load_scenario(maps_dir / "beam_3d.yaml")
    run = simulate(scenario, "secure", seed=0)
    assert not run.collided, run.summary()
    assert run.reached_goal and run.detection_time is not None, run.summary()
    # it went under the beam (bottom at 1.35 m) with its body
    under = (run.positions[:, 0] > 5.0) & (run.positions[:, 0] < 5.3)
    assert under.any() and run.positions[under, 2].max() < 1.35 - 0.2 + 1e-3


def test_min_obstacle_size_is_validated_with_the_file_and_field(maps_dir, tmp_path):
    text = (maps_dir / "thin_pole.yaml").read_text()
    for bad in ("-0.1", "0", "abc"):
        path = tmp_path / "bad.yaml"
        path.write_text(text.replace("min_obstacle_size: 0.04", f"min_obstacle_size: {bad}"))
        with pytest.raises(ScenarioError, match=r"bad\.yaml.*planner\.min_obstacle_size"):
            secure3d.load_scenario(path)


def test_edge_allowance_narrows_every_view_and_the_pole_scene_still_arrives(maps_dir, tmp_path):
    """planner.edge_allowance: true: the problem's frustum gets observed_sides' faces (the NLP,
    the certificate and the guard all read it), the thin-pole scene still arrives without
    collision with every plan certified, and a value other than true/false is refused by name."""
    import dataclasses

    from secure3d.mapping.observability import observed_sides
    from secure3d.planning.problem import problem_from_scenario

    scenario = secure3d.load_scenario(maps_dir / "thin_pole.yaml")
    assert problem_from_scenario(scenario).frustum.side_margin == 0.0  # off by default
    on = dataclasses.replace(
        scenario, planner=dataclasses.replace(scenario.planner, edge_allowance=True)
    )
    f = problem_from_scenario(on).frustum
    cam = scenario.camera
    assert (f.side_margin, f.side_offset, f.side_shrink, f.near) == pytest.approx(
        observed_sides(cam.fx, cam.fy, 0.04)
    )
    run = simulate(on, "secure", seed=0)
    assert not run.collided and run.reached_goal, run.summary()
    assert all(p.certificate is not None and p.certificate.ok for _, p in run.plans)
    text = (maps_dir / "thin_pole.yaml").read_text()
    path = tmp_path / "bad.yaml"
    path.write_text(
        text.replace("min_obstacle_size: 0.04", "min_obstacle_size: 0.04, edge_allowance: 1")
    )
    with pytest.raises(ScenarioError, match=r"bad\.yaml.*planner\.edge_allowance"):
        secure3d.load_scenario(path)
