"""A slot refresh whose re-solve runs away from the solution it refreshes restarts from the guess
(``planning.slot_refresh.REFRESH_RUNAWAY``) or keeps that solution (``KEEP_STALE``), with real
IPOPT solves."""

from __future__ import annotations

import numpy as np
import pytest

import secure3d
from secure3d.planning import lookback as lb
from secure3d.planning import slot_refresh, solve
from secure3d.planning.interrupt import final_time_watch
from secure3d.planning.problem import problem_from_scenario
from secure3d.planning.result import PlanStatus


def _recorded_solves(monkeypatch) -> list[tuple[dict, object, tuple]]:
    """Every _solve_once of the calls that follow: (its keyword arguments, its solve, its start
    (T, X))."""
    calls: list[tuple[dict, object, tuple]] = []
    inner = solve._solve_once

    def recording(problem, planner, assignment, T, X, U, cache, **kw):
        s = inner(problem, planner, assignment, T, X, U, cache, **kw)
        calls.append((kw, s, (T, np.array(X))))
        return s

    monkeypatch.setattr(solve, "_solve_once", recording)
    monkeypatch.setattr(slot_refresh, "_solve_once", recording)
    return calls


@pytest.fixture(scope="module")
def mesh_server(maps_dir):
    """mesh_server: its cold plan's first solution leaves boxes out of its slots (one refresh)."""
    return secure3d.load_scenario(maps_dir / "mesh_server.yaml")


def test_a_refresh_runs_no_restart_on_a_shipped_scene(mesh_server, monkeypatch):
    calls = _recorded_solves(monkeypatch)
    plan = secure3d.plan(mesh_server, "secure")
    assert plan.status is PlanStatus.SUCCESS
    kinds = ["slots" in kw and kw["slots"] is not None for kw, _, _ in calls]
    assert len(calls) == 2 and not any(kinds), [kw.keys() for kw, _, _ in calls]
    assert calls[1][0].get("left_out_limit") is not None  # the refresh, warm from the solution


def test_a_refresh_that_runs_away_restarts_from_the_guess_with_the_left_out_boxes(
    mesh_server, monkeypatch
):
    """With a cap of the solution's own final time every refresh counts as running away: it is
    stopped, and the planner solves again from the round's guess with the refreshed slots, which
    hold every box the first solution came within the margin of. The plan still certifies, at the
    same final time."""
    reference = secure3d.plan(mesh_server, "secure")
    monkeypatch.setattr(slot_refresh, "REFRESH_RUNAWAY", 1.0 + 1e-9)
    calls = _recorded_solves(monkeypatch)
    plan = secure3d.plan(mesh_server, "secure")
    assert plan.status is PlanStatus.SUCCESS and plan.certificate.ok
    assert plan.times[-1] == pytest.approx(reference.times[-1], rel=0.01)
    (_, first, first_start), (kw_ref, refresh, _), (kw_re, restart, restart_start) = calls[:3]
    assert kw_ref.get("left_out_limit") is not None
    assert refresh.status is PlanStatus.ITERATION_LIMIT
    assert "final time ran past" in refresh.message
    assert refresh.T > first.T
    assert kw_re.get("slots") is not None
    assert restart_start[0] == first_start[0]  # from the guess, not from the solution
    assert np.array_equal(restart_start[1], first_start[1])
    problem = problem_from_scenario(mesh_server)
    pairs, _ = lb.left_out_boxes(
        problem, first.X, first.assignment, first.slots, problem.options.margin
    )
    assert len(pairs)
    for k, j in pairs:
        box = np.concatenate([problem.boxes_lo[j], problem.boxes_hi[j]])
        assert np.isclose(restart.slots[k], box).all(axis=1).any(), (k, j)
    assert restart.status is PlanStatus.SUCCESS


def test_a_call_without_slower_guesses_fails_at_a_runaway_refresh_instead_of_restarting(
    mesh_server, monkeypatch
):
    """A replan of a moving robot tries no slower guesses (its fallback is braking), and no
    restart either: the stopped refresh ends the call, well before its budget (it does not keep
    the solution it refreshed: ``KEEP_STALE`` is for calls from rest)."""
    monkeypatch.setattr(slot_refresh, "REFRESH_RUNAWAY", 1.0 + 1e-9)
    calls = _recorded_solves(monkeypatch)
    plan = secure3d.plan(mesh_server, "secure", slower_guesses=False)
    assert plan.status is PlanStatus.ITERATION_LIMIT, plan.status
    assert "final time ran past" in plan.message
    assert len(calls) == 2 and all(kw.get("slots") is None for kw, _, _ in calls)


def _stopped_restarts(monkeypatch) -> list:
    """Make every restart from the guess a real solve that its own final-time watch stops at once
    (a cap far below any final time): the restart that fails. Returns the restarts' solves."""
    real, stopped = slot_refresh.restart_from, []

    def restart(*a, **k):
        with final_time_watch(1e-6):
            r = real(*a, **k)
        stopped.append(r)
        return r

    monkeypatch.setattr(slot_refresh, "restart_from", restart)
    return stopped


def test_a_plan_from_rest_keeps_the_solution_whose_refresh_and_restart_failed(
    mesh_server, monkeypatch
):
    """From rest, a refresh that runs away restarts from the guess; when that fails too, the call
    keeps the solution the refresh started from, its slots stale (``KEEP_STALE``), and the
    certificate judges it: here it finds the box the slots left out too near, and the local
    re-solve that follows certifies, near the reference's final time."""
    reference = secure3d.plan(mesh_server, "secure")
    monkeypatch.setattr(slot_refresh, "REFRESH_RUNAWAY", 1.0 + 1e-9)
    stopped = _stopped_restarts(monkeypatch)
    calls = _recorded_solves(monkeypatch)
    plan = secure3d.plan(mesh_server, "secure")
    assert plan.status is PlanStatus.SUCCESS and plan.certificate.ok, plan.message
    assert plan.times[-1] == pytest.approx(reference.times[-1], rel=0.01)
    assert stopped and all(r.status is PlanStatus.ITERATION_LIMIT for r in stopped)
    first = calls[0][1]
    assert first.status is PlanStatus.SUCCESS
    problem = problem_from_scenario(mesh_server)
    assert lb.slots_stale(problem, "secure", first.X, first.assignment, first.slots)


def test_without_keep_stale_the_failed_restart_costs_the_round(mesh_server, monkeypatch):
    """The rule before ``KEEP_STALE``, for contrast: the failed restart replaced the solution in
    hand, so the call went on to slower guesses and ended with a slower plan."""
    reference = secure3d.plan(mesh_server, "secure")
    monkeypatch.setattr(slot_refresh, "REFRESH_RUNAWAY", 1.0 + 1e-9)
    monkeypatch.setattr(slot_refresh, "KEEP_STALE", False)
    stopped = _stopped_restarts(monkeypatch)
    calls = _recorded_solves(monkeypatch)
    plan = secure3d.plan(mesh_server, "secure")
    assert stopped
    first_start = calls[0][2][0]
    assert max(start[0] for _, _, start in calls) > first_start  # a slower guess was needed
    assert plan.status is not PlanStatus.SUCCESS or plan.times[-1] > 1.02 * reference.times[-1]
