"""The closed loop (paper's Algorithm 1) on real parts: ray-cast camera, voxel map, IPOPT, FCL."""

from __future__ import annotations

import numpy as np
import pytest

import secure3d
from secure3d.errors import SimulationError
from secure3d.mapping import OccupancyMap
from secure3d.simulation.closed_loop import observed_cube, simulate


def test_only_what_the_camera_saw_counts_as_observed_around_the_robot():
    m = OccupancyMap(0.1, bounds=([-5, -5, -5], [5, 5, 5]))
    m.set_claim_boxes([[-5, -5, -5]], [[5, 5, 5]], occupied=False)  # the server says: all free
    assert observed_cube(m, np.zeros(3), 1.0) == 0.0, "claimed free space is not observed space"
    # a dense spherical scan from the origin, walls at 3 m: everything within ~3 m is sensed free
    d = np.random.default_rng(0).normal(size=(20000, 3))
    m.insert_point_cloud(3.0 * d / np.linalg.norm(d, axis=1, keepdims=True), np.zeros(3))
    assert observed_cube(m, np.zeros(3), 1.0) == pytest.approx(1.0)
    assert observed_cube(m, np.array([2.9, 0.0, 0.0]), 1.0) < 0.5, (
        "the cube may not reach unseen space"
    )
    with pytest.raises(SimulationError, match="centre"):
        observed_cube(m, np.array([np.nan, 0.0, 0.0]), 1.0)
    with pytest.raises(SimulationError, match="half_max"):
        observed_cube(m, np.zeros(3), -1.0)


@pytest.mark.slow
def test_blind_corner_secure_flight_sees_the_crate_and_arrives_without_collision(
    maps_dir, tmp_path
):
    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    run = simulate(scenario, "secure", rrd=tmp_path / "secure.rrd", png=tmp_path / "secure.png")
    assert not run.collided, run.summary()
    assert run.reached_goal, run.summary()
    assert run.detection_time is not None, "the hidden crate must be seen"
    assert run.min_clearance > 0
    assert (tmp_path / "secure.rrd").stat().st_size > 0 and (
        tmp_path / "secure.png"
    ).stat().st_size > 0
    assert not list(tmp_path.glob("*.part"))
    # every plan the secure robot followed was certified when it was made
    assert all(p.certificate is not None and p.certificate.ok for _, p in run.plans)
