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


def test_a_solver_exception_ends_the_solve_as_a_solver_error(problem, monkeypatch):
    """When CasADi raises inside a solve (an evaluation error), the solve reports SOLVER_ERROR with
    the first line of the message, no iterations, the start point as its answer, multipliers of
    the NLP's sizes, and the call's slots, assignment and grid; a real solve of the same NLP after
    it carries the same bookkeeping."""
    from secure3d.planning.guess import initial_guess
    from secure3d.planning.nlp_solve import _solve_once

    cache = NLPCache()
    guess = initial_guess(problem, secure=False, speed_fraction=1.0)
    K = problem.options.nodes
    args = (problem, "baseline", (-1,) * K, guess.final_time, guess.states, guess.controls, cache)
    nlp, _ = cache.get(problem, "baseline", (-1,) * K)
    real = nlp.solver

    def failing(**kwargs):
        raise RuntimeError("Error in Function::call for 'nlp_g' [SXFunction]\nNaN detected")

    monkeypatch.setattr(nlp, "solver", failing)
    s = _solve_once(*args)
    assert s.status is PlanStatus.SOLVER_ERROR
    assert s.message == "solver error: Error in Function::call for 'nlp_g' [SXFunction]"
    assert s.iterations == 0 and s.cached and s.assignment == (-1,) * K
    np.testing.assert_array_equal(s.X[1:], guess.states[1:])
    assert s.lam_x.shape == (nlp.layout.n_w,) and not s.lam_x.any()
    assert s.lam_g.shape == (len(nlp.lbg),) and not s.lam_g.any()
    monkeypatch.setattr(nlp, "solver", real)
    ok = _solve_once(*args)
    assert ok.status is PlanStatus.SUCCESS and ok.iterations > 0
    np.testing.assert_array_equal(ok.slots, s.slots)
    assert ok.assignment == s.assignment and ok.grid is None and s.grid is None
