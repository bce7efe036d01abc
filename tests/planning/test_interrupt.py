"""Ctrl-C during an IPOPT solve stops the plan at once (it used to start the next retry)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

_CHILD = """
import secure3d
from secure3d.world.scenario import load_scenario
s = load_scenario("maps/forest.yaml")
for i in range(4):
    r = secure3d.plan(s, "secure", nodes=60)
    print("plan done", r.status.name, flush=True)
"""


def test_ctrl_c_during_a_solve_raises_keyboard_interrupt_within_a_second_or_two():
    child = subprocess.Popen(
        [sys.executable, "-c", _CHILD],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        first = child.stdout.readline()
        assert first.startswith("plan done"), first + child.stderr.read()
        time.sleep(1.0)  # the second plan: NLP cached, so this is IPOPT's time
        child.send_signal(signal.SIGINT)
        t0 = time.perf_counter()
        out, err = child.communicate(timeout=60)
        waited = time.perf_counter() - t0
    finally:
        child.kill()
    assert "KeyboardInterrupt" in err, err[-800:]
    assert out.count("plan done") == 0, f"a plan finished after Ctrl-C: {out!r}"
    assert waited < 5.0, f"{waited:.1f} s from Ctrl-C to exit"


def test_a_plan_call_stops_when_its_wall_time_budget_is_spent(maps_dir):
    """Every solve, retry and re-solve of one call shares plan_budget; a solve running when it
    is spent stops at its next iteration and no further solve starts."""
    import secure3d
    from secure3d.planning.result import PlanStatus

    scenario = secure3d.load_scenario(maps_dir / "forest.yaml")
    full = secure3d.plan(scenario, "secure")
    assert full.status is PlanStatus.SUCCESS and full.iterations > 10
    per_iteration = full.solve_time / full.iterations
    budget = 3 * per_iteration + 0.5 * full.solve_time / full.iterations
    t0 = time.perf_counter()
    cut = secure3d.plan(scenario, "secure", plan_budget=budget)
    wall = time.perf_counter() - t0
    assert cut.status is PlanStatus.TIME_BUDGET, cut.status
    assert cut.iterations < full.iterations
    # the guess and the look-back assignment are not solves: allow for them, not for a retry
    assert wall < budget + 3.0, wall


def test_the_budget_stops_a_solve_before_an_iteration_twice_the_longest_would_overrun(monkeypatch):
    """The iteration callback stops once the budget could be spent by an iteration
    ITERATION_SAFETY times the longest one within the call's budget so far (the solve's set-up
    included), not merely as long as the last one: a short iteration after a long one still stops
    in time for another long one."""
    import types

    from secure3d.planning import interrupt

    clock = types.SimpleNamespace(now=100.0)
    monkeypatch.setattr(interrupt, "time", types.SimpleNamespace(monotonic=lambda: clock.now))
    callback = interrupt.stop_callback(1, 1, 1)
    args = [[0.0]] * 6

    def iteration(seconds: float) -> bool:
        clock.now += seconds
        return bool(callback.eval(args)[0])

    with interrupt.deadline(10.0), interrupt.interruptible():
        assert not iteration(0.5)  # set-up and first iteration
        assert not iteration(2.0)  # a long one: 2.5 s spent, the next might take 4 s
        assert not iteration(0.1)  # 2.6 s: 2.6 + 4.0 < 10
        assert not iteration(0.1)  # 2.7
        stopped = [iteration(1.0) for _ in range(8)]  # 3.7, 4.7, 5.7, 6.7 (+4 >= 10: stop)
    first_stop = stopped.index(True)
    assert first_stop == 3, stopped
    assert interrupt.stopped_for_budget()
    # (with the last iteration's length alone it would have run on to 9.7 s, where an iteration
    # as long as the long one ends at 11.7 s, past the budget)


def test_a_deadline_reserve_is_spent_for_solves_but_not_for_the_work_after_them(monkeypatch):
    import types

    from secure3d.planning import interrupt

    clock = types.SimpleNamespace(now=100.0)
    monkeypatch.setattr(interrupt, "time", types.SimpleNamespace(monotonic=lambda: clock.now))
    with interrupt.deadline(10.0, reserve=1.5):
        clock.now = 108.4
        assert not interrupt.budget_spent() and not interrupt.deadline_passed()
        clock.now = 108.6  # within the reserve: no more solving, certifying goes on
        assert interrupt.budget_spent() and not interrupt.deadline_passed()
        with interrupt.deadline(100.0):  # a nested budget keeps the earlier deadline
            assert not interrupt.budget_spent() and not interrupt.deadline_passed()
        assert interrupt.budget_spent()  # the outer reserve is back
        clock.now = 110.0
        assert interrupt.deadline_passed()
    assert not interrupt.budget_spent() and not interrupt.deadline_passed()


def test_a_certificate_stops_once_the_plan_calls_deadline_has_passed(maps_dir):
    import pytest

    import secure3d
    from secure3d.planning import interrupt
    from secure3d.planning.certificate import certify
    from secure3d.planning.problem import problem_from_scenario

    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    plan = secure3d.plan(scenario, "secure")
    problem = problem_from_scenario(scenario)
    with interrupt.deadline(0.0), pytest.raises(interrupt.BudgetSpent):
        certify(plan, problem)
    assert certify(plan, problem).ok  # outside a plan call: no deadline


def test_a_plan_call_never_certifies_past_its_budget(maps_dir):
    """A solve that ends at the budget leaves no time to certify: the call reports TIME_BUDGET at
    the budget rather than a certificate later (a quadrotor call overran 10 s by 1 s so)."""
    import secure3d
    from secure3d.planning.problem import problem_from_scenario
    from secure3d.planning.result import PlanStatus
    from secure3d.planning.solve import _solve_rounds, plan_problem

    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    budget = 6.0
    problem = problem_from_scenario(scenario, plan_budget=budget)
    t0 = time.perf_counter()

    def solve_then_wait(*args, **kwargs):
        out = _solve_rounds(*args, **kwargs)
        time.sleep(max(0.0, t0 + budget - time.perf_counter()))  # a solve that took the budget
        return out

    result = plan_problem(problem, "secure", solve_rounds=solve_then_wait)
    wall = time.perf_counter() - t0
    assert result.status is PlanStatus.TIME_BUDGET, result.message
    assert "certifying" in result.message
    assert result.iterations > 0
    assert wall < budget + 0.5, wall


def test_a_final_time_watch_stops_a_solve_whose_final_time_passes_its_cap():
    """Inside final_time_watch(cap) the callback stops at the first iterate whose final time
    (variable t_index) is past the cap, and ran_away() tells that stop from the budget's; outside
    the watch, or for an NLP without a final-time index, it never stops for that."""
    from secure3d.planning import interrupt

    watched = interrupt.stop_callback(3, 1, 1, t_index=1)
    blind = interrupt.stop_callback(3, 1, 1)

    def stops(callback, T: float) -> bool:
        return bool(callback.eval([[0.0, T, 0.0]] + [[0.0]] * 5)[0])

    with interrupt.interruptible():
        assert not stops(watched, 50.0)  # no watch: no cap
    assert not interrupt.ran_away()
    with interrupt.final_time_watch(6.0), interrupt.interruptible():
        assert not stops(watched, 5.9) and not stops(watched, 6.0)
        assert not interrupt.ran_away()
        assert not stops(blind, 9.0)
        assert stops(watched, 6.01)
        assert interrupt.final_time_cap() == 6.0
    assert interrupt.ran_away() and not interrupt.stopped_for_budget()
    assert interrupt.final_time_cap() == float("inf")
    with interrupt.interruptible():  # every solve starts with the flag down
        assert not interrupt.ran_away()


def test_a_bad_final_time_cap_or_index_is_refused_by_name():
    import pytest

    from secure3d.errors import PlanningError
    from secure3d.planning import interrupt

    for cap in (0.0, -1.0, float("nan"), "5", True):
        with pytest.raises(PlanningError, match="final_time_watch: cap"):
            with interrupt.final_time_watch(cap):
                pass
    for t_index in (-1, 3, 1.0):
        with pytest.raises(PlanningError, match="stop_callback: t_index"):
            interrupt.stop_callback(3, 1, 1, t_index=t_index)


def test_a_long_solve_logs_its_progress_every_heartbeat(monkeypatch, caplog):
    """A solve longer than SOLVE_HEARTBEAT_SECONDS logs an INFO line with its iterations and final
    time so far, once per heartbeat; a short one logs nothing, and each solve counts afresh."""
    import logging
    import types

    from secure3d.planning import interrupt

    clock = types.SimpleNamespace(now=100.0)
    monkeypatch.setattr(interrupt, "time", types.SimpleNamespace(monotonic=lambda: clock.now))
    monkeypatch.setattr(interrupt, "SOLVE_HEARTBEAT_SECONDS", 5.0)
    callback = interrupt.stop_callback(2, 1, 1, t_index=0)
    args = [[7.25, 0.0]] + [[0.0]] * 5
    caplog.set_level(logging.INFO, logger="secure3d.planning.interrupt")

    def solve(iterations: int, seconds: float) -> list[str]:
        caplog.clear()
        with interrupt.interruptible():
            for _ in range(iterations):
                clock.now += seconds
                assert not callback.eval(args)[0]
        return [r.getMessage() for r in caplog.records if "still solving" in r.getMessage()]

    assert solve(4, 1.0) == []  # 4 s: under one heartbeat
    lines = solve(12, 1.0)  # 12 s: beats at 5 s and 10 s
    assert lines == [
        "still solving: 5 IPOPT iterations in 5 s, final time 7.25 s",
        "still solving: 10 IPOPT iterations in 10 s, final time 7.25 s",
    ], lines
    assert solve(2, 3.0) == ["still solving: 2 IPOPT iterations in 6 s, final time 7.25 s"]
