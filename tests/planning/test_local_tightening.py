"""Certificate re-solves tighten the rows of the nodes around the rejected points, not the whole
plan (issue 16's follow-up): :func:`~secure3d.planning.certificate.failing_nodes` and
:func:`~secure3d.planning.nlp_solve.tightened_bounds`."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import secure3d
from secure3d.planning import lookback as lb
from secure3d.planning.certificate import certify, failing_nodes
from secure3d.planning.collocation import build_nlp
from secure3d.planning.nlp_solve import MARGIN_FAMILIES, tightened_bounds
from secure3d.planning.problem import problem_from_scenario
from secure3d.planning.solve import plan_problem


@pytest.fixture(scope="module")
def corner(maps_dir):
    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    problem = problem_from_scenario(scenario, nodes=20)
    return problem, plan_problem(problem, "secure")


def _margin_rows(nlp) -> np.ndarray:
    return np.concatenate([nlp.families.get(n, np.zeros(0, int)) for n in MARGIN_FAMILIES])


def test_failing_nodes_mark_the_ends_of_the_intervals_that_fail(corner):
    problem, result = corner
    assert result.ok and result.certificate.ok
    # a known box across the middle of the plan: the same plan fails there, and only there
    mid = result.positions[len(result.positions) // 2]
    blocked = dataclasses.replace(
        problem,
        boxes_lo=np.vstack([problem.boxes_lo, mid - 0.3]),
        boxes_hi=np.vstack([problem.boxes_hi, mid + 0.3]),
    )
    cert = certify(result, blocked)
    assert not cert.ok
    marked = failing_nodes(cert, result.times)
    assert marked.shape == (len(result.times),) and set(np.unique(marked)) <= {0.0, 1.0}
    assert 0 < marked.sum() < len(result.times)
    s = cert.sampled
    t_bad = np.unique(s.times[s.owner[cert.views == -2]])
    for t in t_bad:  # every failing time lies in an interval with a marked end
        k = int(np.clip(np.searchsorted(result.times, t, side="right") - 1, 0, len(marked) - 1))
        assert marked[k] == 1.0 or marked[min(k + 1, len(marked) - 1)] == 1.0
    # and every marked node ends an interval with a failing time (no other node is tightened)
    times = result.times
    for k in np.flatnonzero(marked):
        lo, hi = times[max(k - 1, 0)], times[min(k + 1, len(times) - 1)]
        assert np.any((t_bad >= lo - 1e-9) & (t_bad <= hi + 1e-9)), k
    assert marked[: int(np.searchsorted(times, t_bad.min(), side="right")) - 1].sum() == 0
    # a certificate without its sampled plan marks every node
    bare = dataclasses.replace(cert, sampled=None)
    assert failing_nodes(bare, result.times).sum() == len(result.times)


def test_tightened_bounds_raise_only_the_chosen_nodes_margin_rows(corner):
    problem, _ = corner
    K = problem.options.nodes
    nlp = build_nlp(problem, "secure", lb.fixed_assignment(K, problem.options.lookback_steps))
    lbg, _ = nlp.bounds_for(lb.fixed_assignment(K, problem.options.lookback_steps))
    rows = _margin_rows(nlp)
    assert len(nlp.row_node) == len(lbg) and np.all(nlp.row_node[rows] >= 1)
    extra = np.zeros(K)
    extra[7] = 0.05
    out = tightened_bounds(nlp, lbg, extra)
    changed = np.flatnonzero(out != lbg)
    assert len(changed) and np.all(nlp.row_node[changed] == 7)
    assert np.allclose(out[changed] - lbg[changed], 0.05)
    on = np.isfinite(lbg)
    node7 = np.intersect1d(rows, np.flatnonzero((nlp.row_node == 7) & on))
    assert set(changed) == set(node7)  # every finite margin row of node 7, nothing else
    # one number: every margin row; switched-off rows stay off; nothing is ever lowered
    flat = tightened_bounds(nlp, lbg, 0.05)
    assert np.allclose((flat - lbg)[np.intersect1d(rows, np.flatnonzero(on))], 0.05)
    assert np.array_equal(np.isfinite(flat), on)
    assert np.all(tightened_bounds(nlp, lbg, -extra) == lbg)
    assert tightened_bounds(nlp, lbg, np.zeros(K)) is lbg
    # an NLP that does not record its rows' nodes takes the largest everywhere
    bare = dataclasses.replace(nlp, row_node=np.zeros(0, int))
    assert np.array_equal(tightened_bounds(bare, lbg, extra), flat)


def test_the_last_retry_also_raises_the_start_region_rows_of_its_nodes(corner):
    """(2, K): the first row raises the margin rows per node, the second the start-region rows
    (the certificate's last retry, ``START_TIGHTENING``); nothing else moves."""
    from secure3d.planning.nlp_solve import START_FAMILY

    problem, _ = corner
    K = problem.options.nodes
    a = lb.fixed_assignment(K, problem.options.lookback_steps)
    nlp = build_nlp(problem, "secure", a)
    lbg, _ = nlp.bounds_for(a)
    start_rows = nlp.families[START_FAMILY]
    first = int(nlp.row_node[start_rows].min())  # a node that checks the start region
    extra = np.zeros((2, K))
    extra[0, 7], extra[1, first] = 0.05, 0.01
    out = tightened_bounds(nlp, lbg, extra)
    margin_only = tightened_bounds(nlp, lbg, extra[0])
    moved = np.flatnonzero(out != margin_only)
    assert len(moved) and set(moved) <= set(start_rows)
    assert np.all(nlp.row_node[moved] == first) and np.allclose((out - margin_only)[moved], 0.01)
    assert np.array_equal(
        tightened_bounds(nlp, lbg, np.vstack([extra[0], np.zeros(K)])), margin_only
    )
    from secure3d.errors import PlanningError

    with pytest.raises(PlanningError, match=rf"\(2, {K}\), got \(3, {K}\)"):
        tightened_bounds(nlp, lbg, np.zeros((3, K)))


def test_a_tightened_re_solve_that_fails_warm_is_tried_again_cold(monkeypatch):
    """The certificate's re-solve starts warm from the rejected solution's multipliers; when that
    fails it starts again from the solution's primal point alone (the cold barrier schedule)."""
    from types import SimpleNamespace

    from secure3d.planning import judging
    from secure3d.planning.result import PlanStatus

    def solved(status, it):
        return SimpleNamespace(status=status, warm_build=0.0, solve_time=0.1, iterations=it)

    seen = []

    def fake_resolve(problem, planner, s, cache, multipliers, extra):
        seen.append((multipliers is not None, float(np.max(extra))))
        return (
            solved(PlanStatus.ITERATION_LIMIT, 200)
            if multipliers
            else solved(PlanStatus.SUCCESS, 43)
        )

    monkeypatch.setattr(judging, "_resolve_from", fake_resolve)
    monkeypatch.setattr(
        judging, "refreshed", lambda p, pl, t, c, extra_margin: (t, judging.SolveCost())
    )
    rejected = SimpleNamespace(nlp=SimpleNamespace(key="k"), lam_x=np.zeros(2), lam_g=np.zeros(2))
    extra = np.array([0.0, 0.03, 0.03, 0.0])
    out, cost = judging.tightened_solve(None, "secure", rejected, None, extra)
    assert seen == [(True, 0.03), (False, 0.03)]
    assert out.status is PlanStatus.SUCCESS and cost.iterations == 243
    # a warm re-solve that succeeds is kept
    seen.clear()
    monkeypatch.setattr(
        judging,
        "_resolve_from",
        lambda *a: seen.append(a[4] is not None) or solved(PlanStatus.SUCCESS, 9),
    )
    out, cost = judging.tightened_solve(None, "secure", rejected, None, extra)
    assert seen == [True] and cost.iterations == 9


def test_bad_margins_and_node_times_are_refused_by_name(corner):
    from secure3d.errors import PlanningError

    problem, result = corner
    K = problem.options.nodes
    a = lb.fixed_assignment(K, problem.options.lookback_steps)
    nlp = build_nlp(problem, "secure", a)
    lbg, _ = nlp.bounds_for(a)
    with pytest.raises(
        PlanningError, match=rf"one number or {K} \(one per node\), got shape \(3,\)"
    ):
        tightened_bounds(nlp, lbg, np.zeros(3))
    with pytest.raises(PlanningError, match="must be finite"):
        tightened_bounds(nlp, lbg, float("nan"))
    with pytest.raises(PlanningError, match="node times must increase"):
        failing_nodes(result.certificate, result.times[::-1])
