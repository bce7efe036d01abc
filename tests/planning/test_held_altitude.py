"""planning/held_altitude.py: guesses that fly level before ducking, where a narrow vertical view
cannot see a path that climbs or descends at once."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import secure3d
from secure3d.planning import problem_from_scenario
from secure3d.planning.guess import CRAWL_SPEED, _densify, initial_guess
from secure3d.planning.held_altitude import (
    RAMP_LENGTHS,
    RAMP_STARTS,
    held_altitude_paths,
    level_distance,
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


def test_a_plan_that_ducks_under_a_beam_first_flies_level_instead_of_crawling(maps_dir):
    """Seen through a 30 deg vertical view, the shortest path's descent right from the start is
    never in an earlier view: its guess crawled (14.5 s plan, guess at the 0.05 m/s floor)."""
    honest, problem = _beam_known(maps_dir)
    g = initial_guess(problem, secure=True)
    speeds = np.linalg.norm(np.asarray(problem.model.velocity(g.states[1:-1])), axis=-1)
    assert speeds.min() > 2 * CRAWL_SPEED, speeds.min()
    pts, arc = _densify(g.path, 0.1)
    early = arc <= min(RAMP_STARTS) * level_distance(problem) - 0.1  # arc of the 3D path
    np.testing.assert_allclose(pts[early, 2], problem.start_position[2], atol=1e-9)
    r = secure3d.plan(honest, "secure")
    assert r.ok and r.certificate.ok
    assert r.final_time < 10.0, r.final_time  # 14.5 s from the crawling guess
