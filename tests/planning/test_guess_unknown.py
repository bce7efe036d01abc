"""The guess's graph search prefers space some source described over space none did, when the
server's map is made of scans (it claims free space): a lidar survey leaves the inside of walls
unknown, and a guess cutting through it cost a blind-corner survey variant every replan (it held
still for the rest of the run)."""

from __future__ import annotations

import numpy as np
import pytest

import secure3d
from secure3d.errors import PlanningError
from secure3d.mapping.occupancy import OccupancyMap
from secure3d.planning import guess
from secure3d.planning.problem import problem_from_scenario
from secure3d.simulation.campaign_run import plan_campaign
from secure3d.world.attacks import belief_map
from secure3d.world.families import variant_rng


def test_a_map_claims_free_space_only_when_some_claim_is_free():
    m = OccupancyMap(0.1)
    assert not m.claims_free
    m.set_claim_boxes([0.0, 0.0, 0.0], [0.3, 0.3, 0.3], occupied=True)
    assert not m.claims_free
    m.set_claim_boxes([1.0, 0.0, 0.0], [1.3, 0.3, 0.3], occupied=False)
    assert m.claims_free


def test_unknown_cells_cost_more_only_on_a_map_that_claims_free_space(maps_dir):
    base = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    problem = problem_from_scenario(base, belief=belief_map(base))
    points = np.array([[1.0, 1.25, 1.25], [6.75, 6.0, 1.25]])  # legs 1 and 2 of the corridor
    assert not problem.occupancy.claims_free  # the server lists obstacles: no change
    assert np.all(guess.unknown_cost(problem, points) == 1.0)

    problem.occupancy.set_claim_boxes(
        np.array([[0.0, 0.0, 0.0]]), np.array([[8.0, 2.5, 2.5]]), occupied=False
    )
    cost = guess.unknown_cost(problem, points)
    np.testing.assert_array_equal(cost, [1.0, guess.UNKNOWN_COST])
    with pytest.raises(PlanningError, match=r"centres must be \(n, 3\), got shape \(3,\)"):
        guess.unknown_cost(problem, points[0])


@pytest.fixture(scope="module")
def survey_problem(maps_dir, tmp_path_factory):
    """blind_corner's survey variant 1 (seed 5): a lidar survey's stripes on the inner block."""
    base = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    out = tmp_path_factory.mktemp("survey")
    camp = plan_campaign(base, 2, ["secure"], 5, out, "survey", 1, None, None, {})
    scenario = camp.family.variant(camp.prepared, base, variant_rng(5, 1), 1)
    problem = problem_from_scenario(scenario, belief=belief_map(scenario))
    assert problem.occupancy.claims_free
    return problem


def _inside_inner_block(points: np.ndarray) -> np.ndarray:
    lo, hi = np.array([-0.5, 2.5, 0.0]), np.array([5.5, 9.0, 2.5])
    return np.all((points > lo) & (points < hi), axis=1)


def _dense(path: np.ndarray) -> np.ndarray:
    """Points every 1/20 of each segment of a polyline (n, 3)."""
    return np.concatenate([np.linspace(a, b, 20) for a, b in zip(path[:-1], path[1:], strict=True)])


def test_the_survey_guess_keeps_to_the_corridor_the_survey_saw(survey_problem, monkeypatch):
    path = guess.graph_path(survey_problem)
    dense = _dense(path)
    assert not _inside_inner_block(dense).any()
    # with unknown space as cheap as described space, the search cuts through the block's
    # undescribed inside (between the survey's stripes), as every guess did before
    monkeypatch.setattr(guess, "UNKNOWN_COST", 1.0)
    path = guess.graph_path(survey_problem)
    dense = _dense(path)
    assert _inside_inner_block(dense).any()
