"""planning/solve.py: what plan_problem refuses or reports before any solve."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import secure3d
from secure3d.errors import ConfigError
from secure3d.planning import NLPCache, PlanStatus, plan_problem, problem_from_scenario


@pytest.fixture(scope="module")
def problem(maps_dir):
    return problem_from_scenario(secure3d.load_scenario(maps_dir / "blind_corner.yaml"))


def test_an_unknown_planner_is_refused_before_anything_is_built(problem):
    cache = NLPCache()
    with pytest.raises(ConfigError, match="planner: must be 'secure' or 'baseline', got 'fast'"):
        plan_problem(problem, "fast", cache=cache)
    assert len(cache) == 0


def test_a_goal_outside_the_map_is_reported_without_a_solve(problem):
    outside = dataclasses.replace(problem, goal=np.asarray(problem.bounds_hi) + 1.0)
    cache = NLPCache()
    result = plan_problem(outside, "baseline", cache=cache)
    assert result.status is not PlanStatus.SUCCESS
    assert "goal" in result.message and "outside the map bounds" in result.message
    assert len(cache) == 0, "no NLP was built"
