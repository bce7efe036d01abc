"""Closed loop over a server map given as a mesh: the secure planner arrives without collision,
the baseline (trusting the stale mesh) hits the crate it lacks. Real IPOPT, ray casting, FCL."""

from __future__ import annotations

from pathlib import Path

import pytest

from secure3d.session import simulate

MAPS = Path(__file__).resolve().parents[2] / "maps"


@pytest.mark.parametrize("planner", ["secure", "baseline"])
def test_mesh_server_map_in_closed_loop(planner: str, tmp_path: Path) -> None:
    r = simulate(MAPS / "mesh_server.yaml", planner=planner, png=tmp_path / "run.png")
    assert (tmp_path / "run.png").stat().st_size > 10_000
    if planner == "secure":
        assert not r.collided and r.reached_goal
        # the mesh predates the crate (server_map.lacks): its first sight is reported
        assert r.detection_time is not None and 0.0 < r.detection_time < r.time_to_goal
    else:
        assert r.collided and "crate" in r.collision_obstacles


def test_scan_graph_server_map_in_closed_loop(tmp_path: Path) -> None:
    """warehouse_survey: the server map is an OctoMap scan graph of a survey that predates the
    barrel round shelf_2's end. The secure robot sees the barrel and arrives without a collision.
    (With the scenario's own 50 nodes it sees the barrel late and brakes short of the goal first:
    ``test_flight``'s goal-edge test flies that.)"""
    r = simulate(MAPS / "warehouse_survey.yaml", planner="secure")
    assert not r.collided and r.reached_goal, r.summary()
    assert r.time_to_goal < 10.0
