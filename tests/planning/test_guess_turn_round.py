"""The initial guess of a turn-in-place vehicle whose route leaves behind it (issue 16, dead ends)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import secure3d
from secure3d.planning.guess import initial_guess, stop_and_turn
from secure3d.planning.problem import problem_from_scenario
from secure3d.planning.solve import plan_problem


def test_stop_and_turn_brakes_to_rest_then_turns_on_the_spot():
    t, p, v, yaw = stop_and_turn(np.zeros(3), 1.2, 0.0, np.pi, a_max=1.2, yaw_rate=3.0)
    assert np.all(np.diff(t) > 0) and t[0] == 0.0
    speed = v @ np.array([1.0, 0.0, 0.0])
    assert speed[0] == pytest.approx(1.2) and np.all(np.diff(speed) <= 1e-12)
    assert np.allclose(v[-1], 0.0) and yaw[-1] == pytest.approx(np.pi)
    assert p[-1, 0] == pytest.approx(1.2**2 / (2 * 1.2))  # the braking distance, along the heading
    moving = np.linalg.norm(v, axis=1) > 1e-9
    assert np.all(yaw[moving] == 0.0), "no turning while still driving"
    rate = np.abs(np.diff(yaw)) / np.diff(t)
    assert rate.max() <= 0.7 * 3.0 + 1e-9


def _facing_the_dead_end(maps_dir):
    """planar_dead_end with its dead end known, the robot driving at it at 1.3 m/s."""
    sc = secure3d.load_scenario(maps_dir / "planar_dead_end.yaml")
    honest = dataclasses.replace(sc, server_map=dataclasses.replace(sc.server_map, attacks=()))
    problem = problem_from_scenario(honest, nodes=40, plan_budget=60.0)
    x0 = problem.model.initial_state((2.15, 2.83, 0.5), (1.3, 0.0, 0.0), 0.0)
    return problem.with_start(x0, half_size=1.0)


def test_a_diff_drive_facing_a_dead_end_turns_round_in_its_guess_and_plan(maps_dir):
    problem = _facing_the_dead_end(maps_dir)
    guess = initial_guess(problem, secure=True)
    yaw, t = guess.states[:, 2], guess.times
    # the heading changes at most as fast as the robot can turn: no flip by pi in one node
    assert np.max(np.abs(np.diff(yaw)) / np.diff(t)) <= problem.model.limits.max_ang_speed
    assert np.abs(yaw - yaw[0]).max() > np.pi / 2, "it turns round"
    result = plan_problem(problem, "secure")
    assert result.ok and result.certificate.ok, result.message
    assert result.iterations < 400
    pos = result.positions
    assert pos[:, 0].min() < 1.5, "it goes back out of the closed corridor"


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"a_max": 0.0}, "a_max must be > 0"),
        ({"yaw_rate": float("nan")}, "yaw_rate must be > 0"),
        ({"p0": np.zeros(2)}, "p0 must be 3 finite numbers"),
        ({"v0": float("inf")}, "v0"),
    ],
)
def test_stop_and_turn_names_a_bad_input(kwargs, needle):
    from secure3d.errors import PlanningError

    args = {"p0": np.zeros(3), "v0": 1.0, "yaw0": 0.0, "yaw1": np.pi, "a_max": 1.0, "yaw_rate": 3.0}
    args.update(kwargs)
    with pytest.raises(PlanningError, match=needle):
        stop_and_turn(**args)
