"""planning/visible_paths.py: where a narrow vertical view makes the shortest path's guess crawl,
guesses that fly level before ducking, or back away from the start's view before they go."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import secure3d
from secure3d.planning import problem_from_scenario
from secure3d.planning.guess import (
    CANDIDATE_GAIN,
    _crawls,
    centre_path,
    graph_path,
    initial_guess,
    profile_guess,
)
from secure3d.planning.lookback import node_geometry, start_margins
from secure3d.planning.solve import plan_problem
from secure3d.planning.visible_paths import (
    BACK_OFF_FRACTIONS,
    RAMP_LENGTHS,
    RAMP_STARTS,
    held_altitude_paths,
    level_distance,
    stepped_back_paths,
)


def _beam_known(maps_dir, **options):
    """beam_3d with the beam on the server map: the route must duck under it, 4 m ahead."""
    sc = secure3d.load_scenario(maps_dir / "beam_3d.yaml")
    honest = dataclasses.replace(sc, server_map=dataclasses.replace(sc.server_map, attacks=()))
    return honest, problem_from_scenario(honest, **options)


def test_candidates_hold_the_start_height_then_join_the_path_and_keep_its_clearance(maps_dir):
    _, problem = _beam_known(maps_dir)
    arc = np.linspace(0.0, 8.4, 85)
    pts = np.stack([0.8 + arc, np.full_like(arc, 1.5), 1.5 - 0.6 * np.sin(np.pi * arc / 8.4)], 1)
    d = level_distance(problem)
    assert d == pytest.approx(problem.model.body_radius / np.sin(problem.frustum.vfov / 2))
    cands = held_altitude_paths(problem, pts, arc)
    assert 1 <= len(cands) <= len(RAMP_STARTS) * len(RAMP_LENGTHS)
    clear = problem.box_index.min_distance(pts)
    for c in cands:
        np.testing.assert_array_equal(c[:, :2], pts[:, :2])  # the same horizontal course
        held = arc <= min(RAMP_STARTS) * d
        np.testing.assert_allclose(c[held, 2], 1.5)  # the start's height at first
        joined = arc >= (max(RAMP_STARTS) + max(RAMP_LENGTHS)) * d
        np.testing.assert_allclose(c[joined, 2], pts[joined, 2])  # the path's own later
        need = np.minimum(clear, problem.model.body_radius + problem.options.margin)
        assert np.all(problem.box_index.min_distance(c) >= need - 1e-12)


def test_no_candidate_where_holding_the_height_would_hit_an_obstacle_or_change_nothing(maps_dir):
    _, problem = _beam_known(maps_dir)
    arc = np.linspace(0.0, 8.4, 85)
    level = np.stack([0.8 + arc, np.full_like(arc, 1.5), np.full_like(arc, 1.5)], 1)
    assert held_altitude_paths(problem, level, arc) == []  # a level path is its own candidate
    # ducking at once under a beam 0.5 m ahead: held level, the path would meet the beam
    box = dataclasses.replace(
        problem,
        boxes_lo=np.vstack([problem.boxes_lo, [1.3, 0.0, 1.35]]),
        boxes_hi=np.vstack([problem.boxes_hi, [1.6, 3.0, 2.6]]),
    )
    duck = level.copy()
    duck[:, 2] = np.where(arc < 0.3, 1.5 - arc, 1.0)
    duck[(arc > 3.0), 2] = 1.0 + np.minimum(arc[arc > 3.0] - 3.0, 0.5)
    assert held_altitude_paths(box, duck, arc) == []
    planar = problem_from_scenario(secure3d.load_scenario(maps_dir / "planar_blind_corner.yaml"))
    assert held_altitude_paths(planar, level, arc) == []


def _plain_guess(problem):
    """The shortest path's visibility-aware time scaling, without candidates."""
    path = centre_path(problem, graph_path(problem))
    return profile_guess(problem, path, problem.options.guess_speed_fraction, True)


def test_a_plan_that_ducks_under_a_beam_no_longer_starts_from_a_crawl(maps_dir):
    """Seen through a 30 deg vertical view, the shortest path's descent right from the start is
    never in an earlier view: its guess crawled (28 s) and the plan took 14.5 s."""
    honest, problem = _beam_known(maps_dir)
    plain = _plain_guess(problem)
    assert _crawls(problem, plain)
    assert initial_guess(problem, secure=True).final_time <= CANDIDATE_GAIN * plain.final_time
    r = secure3d.plan(honest, "secure")
    assert r.ok and r.certificate.ok
    assert r.final_time < 10.0, r.final_time  # 14.5 s from the crawling guess


def _narrow_forest(maps_dir):
    """forest's quadrotor with a 34 deg vertical view (the occlusion3d family's): its reactive set
    at rest fits that view only from 1.25 m ahead; the 1 m start region holds it up to 0.7 m."""
    problem = problem_from_scenario(
        secure3d.load_scenario(maps_dir / "forest.yaml"), plan_budget=15.0
    )
    return dataclasses.replace(problem, frustum=dataclasses.replace(problem.frustum, vfov=0.59))


def test_stepped_back_candidates_back_away_from_the_view_inside_the_start_region(maps_dir):
    problem = _narrow_forest(maps_dir)
    path = centre_path(problem, graph_path(problem))
    cands = stepped_back_paths(problem, path)
    assert len(cands) == len(BACK_OFF_FRACTIONS)
    start, yaw = problem.start_position, float(problem.model.yaw(problem.x0))
    backs = []
    for c in cands:
        np.testing.assert_array_equal(c[0], start)
        np.testing.assert_array_equal(c[2:], path)  # back to the start, then the path itself
        step = c[1] - c[0]
        backs.append(np.linalg.norm(step))
        np.testing.assert_allclose(step / backs[-1], [-np.cos(yaw), -np.sin(yaw), 0.0], atol=1e-12)
        line = start + np.linspace(0.0, 1.0, 21)[:, None] * step
        rest = problem.model.initial_states(line, np.zeros_like(line), np.full(len(line), yaw))
        margins = start_margins(problem, node_geometry(problem, rest))
        assert np.all(margins >= problem.options.margin - 1e-12)
    np.testing.assert_allclose(backs[0] / backs[1], BACK_OFF_FRACTIONS[0] / BACK_OFF_FRACTIONS[1])
    # the farthest back-off is the farthest the start region allows (to the search's 5 cm step)
    beyond = start + (backs[1] + 0.05) * (cands[1][1] - start) / backs[1]
    rest = problem.model.initial_states(beyond[None], np.zeros((1, 3)), np.array([yaw]))
    assert start_margins(problem, node_geometry(problem, rest))[0] < problem.options.margin
    # a robot that heads where it goes would have to turn round: no candidate
    planar = problem_from_scenario(secure3d.load_scenario(maps_dir / "planar_blind_corner.yaml"))
    assert stepped_back_paths(planar, path) == []


def test_a_narrow_view_quadrotor_backs_away_first_and_its_plan_is_certified(maps_dir):
    """Before the candidates, this plan ran out of a 15 s budget (T 25 s, 334 iterations)."""
    problem = _narrow_forest(maps_dir)
    plain = _plain_guess(problem)
    assert _crawls(problem, plain)
    g = initial_guess(problem, secure=True)
    assert g.final_time <= CANDIDATE_GAIN * plain.final_time
    p = np.asarray(problem.model.position(g.states))
    assert p[:, 0].min() < problem.start_position[0] - 0.1  # it backs away along -x first
    r = plan_problem(problem, "secure")
    assert r.ok and r.certificate.ok, r.message
    assert r.final_time < 10.0, r.final_time


def test_a_moving_robot_gets_no_stepped_back_candidate(maps_dir):
    """Backing away from a moving start would mean braking and reversing first."""
    problem = _narrow_forest(maps_dir)
    path = centre_path(problem, graph_path(problem))
    moving = problem.x0.copy()
    moving[3] = 1.0  # 1 m/s along x (the quadrotor's state: position, velocity, ...)
    np.testing.assert_allclose(problem.model.velocity(moving), [1.0, 0.0, 0.0])
    assert stepped_back_paths(dataclasses.replace(problem, x0=moving), path) == []


def test_malformed_paths_are_refused_by_name(maps_dir):
    from secure3d.errors import PlanningError

    _, problem = _beam_known(maps_dir)
    arc = np.linspace(0.0, 2.0, 5)
    pts = np.stack([arc, np.ones(5), np.ones(5)], 1)
    with pytest.raises(PlanningError, match="points: must be a finite \\(n, 3\\) array"):
        held_altitude_paths(problem, pts[:, :2], arc)
    with pytest.raises(PlanningError, match="points: must be a finite"):
        stepped_back_paths(problem, np.where(pts > 1.5, np.nan, pts))
    with pytest.raises(PlanningError, match="arc: must be 5 finite arc lengths"):
        held_altitude_paths(problem, pts, arc[:4])
    with pytest.raises(PlanningError, match="arc: must start at 0 and never decrease"):
        held_altitude_paths(problem, pts, arc[::-1])
