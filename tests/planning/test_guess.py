"""planning/guess.py: the initial guess reads the vehicle's capabilities, not its name."""

from __future__ import annotations

import numpy as np
import pytest

import secure3d
from secure3d.planning import problem_from_scenario
from secure3d.planning.guess import initial_guess, look_ahead_yaw


@pytest.mark.parametrize("name", ["blind_corner.yaml", "planar_blind_corner.yaml"])
def test_the_guess_starts_at_the_start_ends_at_the_goal_and_keeps_the_speed_limit(maps_dir, name):
    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / name))
    model = problem.model
    g = initial_guess(problem)
    P = np.asarray(model.position(g.states))
    np.testing.assert_allclose(P[0], problem.start_position, atol=1e-9, err_msg=name)
    np.testing.assert_allclose(P[-1], np.asarray(problem.goal)[:3], atol=1e-6, err_msg=name)
    assert np.all(model.speed(g.states) <= model.speed_limit * (1 + 1e-9)), name
    assert g.final_time > 0
    if model.planar:  # a planar robot's guess stays at its height
        np.testing.assert_allclose(P[:, 2], problem.start_position[2], atol=1e-9, err_msg=name)


def test_a_robot_that_heads_where_it_goes_faces_the_path_tangent():
    arc = np.linspace(0.0, 4.0, 41)
    points = np.stack([arc, np.zeros_like(arc), np.ones_like(arc)], axis=1)
    points[20:, 1] = arc[20:] - arc[20]  # a 45-degree turn half way
    yaw = look_ahead_yaw(points, arc, 0.0, 0.0)
    np.testing.assert_allclose(yaw[:15], 0.0, atol=1e-12)
    np.testing.assert_allclose(yaw[25:], np.pi / 4, atol=1e-12)
