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
