"""Warm replans that keep the previous plan's later nodes (time-grid parameter of the NLP)."""

from __future__ import annotations

import numpy as np
import pytest

import secure3d
from secure3d.errors import PlanningError
from secure3d.planning import certify, plan_problem, problem_from_scenario
from secure3d.planning.collocation import NLPCache, node_fractions
from secure3d.planning.trajectory import interpolate, remainder_keeping_nodes, resample


@pytest.fixture(scope="module")
def corner_problem(maps_dir):
    return problem_from_scenario(secure3d.load_scenario(maps_dir / "blind_corner.yaml"))


@pytest.fixture(scope="module")
def cold(corner_problem):
    cache = NLPCache()
    return cache, plan_problem(corner_problem, "secure", cache=cache)


@pytest.mark.parametrize("t_start", [0.0, 0.1, 0.35, 1.0, 1.8])
def test_remainder_keeps_later_nodes_exactly(cold, corner_problem, t_start):
    plan = cold[1]
    model = corner_problem.model
    times, X, U = remainder_keeping_nodes(model, plan.times, plan.states, plan.controls, t_start)
    K = len(plan.times)
    assert times.shape == (K,) and X.shape == plan.states.shape and U.shape == plan.controls.shape
    assert times[0] == 0.0 and np.all(np.diff(times) > 0)
    np.testing.assert_allclose(times[-1], plan.final_time - t_start)
    # node 0 is the state reached at t_start; a suffix of nodes is the old plan's, node for node
    x0, _ = interpolate(model, plan.times, plan.states, plan.controls, np.array([t_start]))
    np.testing.assert_allclose(X[0], x0[0])
    kept = np.isclose((times + t_start)[:, None], plan.times[None, 1:], rtol=0, atol=1e-12).any(1)
    kept[0] = False  # node 0 is the new start, even at t_start = 0
    first = int(np.argmax(kept))
    assert kept[first:].all() and not kept[:first].any() and first >= 1
    np.testing.assert_array_equal(X[first:], plan.states[first:])
    np.testing.assert_array_equal(U[first:], plan.controls[first:])
    # the nodes in front are evenly spaced and at least half a mean step apart
    front = np.diff(times[: first + 1])
    np.testing.assert_allclose(front, front[0])
    assert front[0] >= 0.5 * plan.final_time / (K - 1) - 1e-12


@pytest.mark.parametrize("fraction", [0.7, 0.999])
def test_remainder_late_in_the_plan_falls_back(cold, corner_problem, fraction):
    """Past half the plan the nodes passed no longer fit in front at half a step apart."""
    plan = cold[1]
    args = (corner_problem.model, plan.times, plan.states, plan.controls)
    t_start = fraction * plan.final_time
    assert remainder_keeping_nodes(*args, t_start) is None
    times, _, _ = resample(*args, t_start, len(plan.times))
    assert len(times) == len(plan.times)


def test_remainder_rejects_bad_arguments(cold, corner_problem):
    plan = cold[1]
    args = (corner_problem.model, plan.times, plan.states, plan.controls)
    with pytest.raises(PlanningError, match="t_start"):
        remainder_keeping_nodes(*args, float("nan"))
    with pytest.raises(PlanningError, match="min_gap"):
        remainder_keeping_nodes(*args, 0.1, min_gap=0.0)
    with pytest.raises(PlanningError, match="increasing"):
        remainder_keeping_nodes(
            corner_problem.model, plan.times[::-1], plan.states, plan.controls, 0.1
        )


def test_node_fractions_are_checked():
    np.testing.assert_allclose(node_fractions(np.array([0.0, 1.0, 4.0]), 3), [0, 0.25, 1])
    for bad in ([0.0, 2.0, 1.0], [0.1, 0.5, 1.0], [0.0, 1.0]):
        with pytest.raises(ValueError, match="increasing"):
            node_fractions(np.array(bad), 3)


@pytest.mark.parametrize("dt", [0.1, 0.5])
def test_warm_replan_along_the_plan_keeps_nodes_and_certifies(cold, corner_problem, dt):
    cache, plan = cold
    model = corner_problem.model
    x, _ = interpolate(model, plan.times, plan.states, plan.controls, np.array([dt]))
    moved = corner_problem.with_start(x[0])
    misses = cache.misses
    warm = plan_problem(moved, "secure", cache=cache, warm=plan, warm_time=dt)
    assert warm.ok, warm.message
    assert cache.misses == misses, "same NLP: the time grid is a parameter"
    # an uneven grid: the kept nodes are where the previous plan had them, rescaled with T
    steps = np.diff(warm.times)
    assert steps.max() - steps.min() > 1e-3
    np.testing.assert_allclose(warm.times, warm.final_time * warm.warm.grid)
    if dt < plan.times[1]:  # only node 0 passed: every other node is the old one
        assert warm.iterations <= 12, warm.iterations
    # about as fast as the rest of the cold plan (the start region moved with the start; the
    # resampled warm start of before ended 0.45 s slower at dt = 0.5)
    assert warm.final_time <= plan.final_time - dt + 0.1
    # the certificate judges the uneven grid on its own (dense sampling between the real times)
    cert = certify(warm, moved)
    assert cert.ok, str(cert)
    # the dynamics hold on the uneven grid: the interpolant reaches the goal at rest
    xe, _ = interpolate(model, warm.times, warm.states, warm.controls, warm.times[-1:])
    np.testing.assert_allclose(model.velocity(xe)[0], 0.0, atol=1e-4)


def test_warm_replan_without_multipliers_uses_the_cold_solver(corner_problem):
    """The fall-back of a failed warm start: the kept nodes, primal only, cold barrier schedule."""
    from secure3d.planning.guess import guess_from_plan
    from secure3d.planning.solve import _solve_rounds

    cache = NLPCache()
    plan = plan_problem(corner_problem, "secure", cache=cache)
    x, _ = interpolate(
        corner_problem.model, plan.times, plan.states, plan.controls, np.array([0.1])
    )
    moved = corner_problem.with_start(x[0])
    guess = guess_from_plan(moved, plan, 0.1)
    s, cost = _solve_rounds(moved, "secure", guess, plan, 0.1, cache, dual_start=False)
    assert s.status.ok and cost.iterations > 0 and cost.build == 0.0
    assert s.nlp.warm_solver is None, "primal-only: the warm-start solver is never compiled"
    assert s.grid is not None and np.ptp(np.diff(s.grid)) > 1e-6, "still on the kept nodes"
    s2, cost2 = _solve_rounds(moved, "secure", guess, plan, 0.1, cache, dual_start=True)
    assert s2.status.ok and s2.nlp.warm_solver is not None and cost2.build > 0.0


def test_secure_plan_warm_started_from_the_baseline(corner_problem, cold):
    """The baseline's path, time-scaled for the secure planner, then a cold secure solve (the
    baseline's duals and all-start-region look-back would make it infeasible)."""
    cache = cold[0]
    base = plan_problem(corner_problem, "baseline", cache=cache)
    assert base.ok
    result = plan_problem(corner_problem, "secure", cache=cache, warm=base)
    assert result.ok, result.message
    assert result.certificate is not None and result.certificate.ok
    assert (result.lookback[1:] >= 0).any(), "nodes seen from earlier nodes, not all start region"
    assert result.final_time < 1.2 * cold[1].final_time


def test_interpolate_with_kept_node_derivatives(cold, corner_problem):
    """A tracker keeps the node derivatives of the plan it follows: the same reading, and a
    mismatched array is refused."""
    from secure3d.planning.trajectory import node_derivatives

    plan, model = cold[1], corner_problem.model
    t = np.linspace(-0.1, plan.final_time + 0.1, 37)
    F = node_derivatives(model, plan.states, plan.controls)
    assert F.shape == plan.states.shape
    x0, u0 = interpolate(model, plan.times, plan.states, plan.controls, t)
    from secure3d.planning.trajectory import Interpolant

    x1, u1 = Interpolant(model, plan.times, plan.states, plan.controls, F)(t)
    np.testing.assert_array_equal(x1, x0)
    np.testing.assert_array_equal(u1, u0)
    with pytest.raises(PlanningError, match="derivatives"):
        Interpolant(model, plan.times, plan.states, plan.controls, F[:-1])
    # an Interpolant read one time at a time, as the tracker does: the same values
    reader = Interpolant(model, plan.times, plan.states, plan.controls)
    for i, ti in enumerate(t):
        xi, ui = reader(np.array([ti]))
        np.testing.assert_array_equal(xi[0], x0[i])
        np.testing.assert_array_equal(ui[0], u0[i])
    with pytest.raises(PlanningError, match="increasing"):
        Interpolant(model, plan.times[::-1], plan.states, plan.controls)
