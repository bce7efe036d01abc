"""Exploration under denial: a map that shows no route makes the robot go and look, not hold."""

from __future__ import annotations

import dataclasses

import numpy as np

import secure3d
from secure3d.simulation.closed_loop import simulate
from secure3d.world.families import family_variants
from secure3d.world.family_registry import FAMILIES


def _short(scenario, limit: float):
    return dataclasses.replace(
        scenario, simulation=dataclasses.replace(scenario.simulation, time_limit=limit)
    )


def test_a_shifted_wall_that_closes_the_only_corridor_is_looked_at_and_passed(maps_dir):
    scenario = secure3d.load_scenario(maps_dir / "shifted_wall_denial.yaml")
    held = simulate(_short(scenario, 8.0), "secure", explore=False)
    assert not held.reached_goal and not held.plans, held.summary()
    run = simulate(scenario, "secure")
    assert run.reached_goal and not run.collided, run.summary()
    kinds = [e.kind for e in run.events]
    assert "explore" in kinds and "looking" in kinds
    assert kinds.index("explore") < kinds.index("goal reached")


def test_no_exploration_while_the_map_shows_a_route(maps_dir):
    from secure3d.planning.problem import problem_from_scenario
    from secure3d.simulation.explore import viewpoint_for_denial
    from secure3d.world.attacks import belief_map

    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    belief = belief_map(scenario)
    lo, hi = belief.known_obstacle_boxes()
    problem = problem_from_scenario(scenario, belief=belief, obstacle_boxes=(lo, hi))
    assert viewpoint_for_denial(problem, belief) is None


def test_the_denial_family_closes_the_route_and_keeps_start_and_goal_clear(maps_dir):
    from secure3d.planning.guess import NoPathError, graph_path
    from secure3d.planning.problem import problem_from_scenario
    from secure3d.world.attacks import belief_map

    base = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    variants = family_variants(FAMILIES["denial"], base, 3, seed=7)
    again = family_variants(FAMILIES["denial"], base, 3, seed=7)
    for v, w in zip(variants, again, strict=True):
        assert v.server_map.attacks == w.server_map.attacks  # a pure function of (base, seed, i)
        slab = v.server_map.attacks[-1]
        assert slab.kind == "phantom" and slab.region is not None
        belief = belief_map(v)
        problem = problem_from_scenario(
            v, belief=belief, obstacle_boxes=belief.known_obstacle_boxes()
        )
        try:
            graph_path(problem)
        except NoPathError:
            pass
        else:
            raise AssertionError(f"{v.name}: the claimed slab leaves a route")
        for end in (v.start.position, v.goal.position):
            inside = np.all((np.array(end) >= slab.region.lo) & (np.array(end) <= slab.region.hi))
            assert not inside
