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
    else:
        assert r.collided and "crate" in r.collision_obstacles
