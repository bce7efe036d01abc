"""The paper's experiments (maps/paper_*.yaml and ``secure3d paper``), with real IPOPT solves."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from secure3d.cli import main
from secure3d.paper import MAPS, PAPER_CORNER, PAPER_PASSAGES
from secure3d.planning import NLPCache, plan
from secure3d.world import load_scenario


def _min_time_to_rest(distance: float, v0: float, accel: float, v_max: float) -> float:
    """Fastest straight run from speed v0 to rest over ``distance`` (bang-bang, speed-capped)."""
    peak = math.sqrt(accel * distance + v0**2 / 2)
    if peak <= v_max:
        return (peak - v0) / accel + peak / accel
    cruise = distance - (v_max**2 - v0**2) / (2 * accel) - v_max**2 / (2 * accel)
    return (v_max - v0) / accel + cruise / v_max + v_max / accel


def test_the_passages_slow_the_secure_robot_as_in_the_paper() -> None:
    cache = NLPCache()
    times = {}
    for name, paper_time in PAPER_PASSAGES.items():
        scenario = load_scenario(MAPS / f"{name}.yaml")
        secure = plan(scenario, "secure", cache=cache)
        baseline = plan(scenario, "baseline", cache=cache)
        assert secure.ok and baseline.ok, (name, secure.message, baseline.message)
        assert abs(secure.final_time / paper_time - 1) <= 0.25, (name, secure.final_time)
        # the baseline is a straight run: the guess must not leave it in a detour
        bound = _min_time_to_rest(2.5, 1.0, 3.0, 3.0)
        assert bound * 0.98 <= baseline.final_time <= bound * 1.02, (name, baseline.final_time)
        assert secure.final_time >= baseline.final_time - 1e-6
        times[name] = secure.final_time
    # The narrower passage slows the secure robot, as in the paper (1.60 -> 2.12 s). Since the
    # diff drive's rest row is well conditioned (planning.constraints.rest_rows) IPOPT finds a
    # faster certified 20 cm plan (1.70 s, was 2.00 s), so the ratio is 1.07, not the paper's 1.33.
    assert times["paper_passage_20cm"] > times["paper_passage_50cm"], times


def test_the_blind_corner_plans_are_near_the_papers() -> None:
    scenario = load_scenario(MAPS / "paper_blind_corner.yaml")
    cache = NLPCache()
    plans = {p: plan(scenario, p, cache=cache) for p in ("secure", "baseline")}
    for planner, result in plans.items():
        assert result.ok, (planner, result.message)
        assert abs(result.final_time / PAPER_CORNER[planner] - 1) <= 0.25, (planner, result)
    assert plans["baseline"].final_time < plans["secure"].final_time


def test_paper_quick_writes_its_figures_recordings_and_table(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "paper"
    assert main(["paper", "--quick", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "secure3d paper [" in captured.err, "progress lines go to stderr"
    expected = [
        "one_d_reactive_sets.png",
        "passages.png",
        "passages_speed.png",
        "paper_passage_50cm.rrd",
        "paper_passage_20cm.rrd",
        "corner_secure.png",
        "corner_baseline.png",
        "corner_secure.rrd",
        "corner_baseline.rrd",
        "paper.md",
    ]
    for name in expected:
        assert (out / name).stat().st_size > 0, name
        assert f"wrote {out / name}" in captured.out
    assert not list(out.glob(".*.part")), "no temporary file left behind"
    table = (out / "paper.md").read_text()
    rows = {tuple(c.strip() for c in line.split("|")[1:3]): line for line in table.splitlines()}
    for key in [("paper_passage_50cm", "secure"), ("blind corner, closed loop", "baseline")]:
        assert key in rows, key
    secure_flight = rows[("blind corner, closed loop", "secure")]
    assert "collided" not in secure_flight.split("|")[-2]
    assert "saw the obstacle" in secure_flight
    assert "max error 0.000 m" in table


def test_in_closed_loop_the_baseline_hits_the_hidden_box_and_the_secure_robot_does_not() -> None:
    from secure3d.paper import CORNER_FLIGHT
    from secure3d.simulation.closed_loop import simulate

    scenario = load_scenario(MAPS / "paper_blind_corner.yaml")
    secure = simulate(scenario, "secure", **CORNER_FLIGHT)
    assert not secure.collided and secure.detection_time is not None, secure.summary()
    assert secure.reached_goal, secure.summary()
    # the closed loop's own 12 obstacle slots: its first baseline solve stalls at the final
    # time's cap (T 9.98 s of 10) unless such a solve counts as failed and the next guess is tried
    baseline = simulate(scenario, "baseline", replan_in_flight=False)
    assert baseline.plans[0][1].final_time < 2.0, baseline.plans[0][1].final_time
    assert baseline.collided and baseline.collision_obstacles == ("unknown_box",)
    assert baseline.detection_time is not None and baseline.detection_time < baseline.collision_time


def test_ctrl_c_during_the_flights_keeps_the_finished_files_and_no_partial_one(
    tmp_path: Path,
) -> None:
    import signal
    import subprocess
    import sys

    out = tmp_path / "paper"
    cmd = [sys.executable, "-m", "secure3d", "paper", "--quick", "--out", str(out)]
    child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    lines = []
    for line in child.stderr:
        lines.append(line)
        if "flying both planners" in line:
            child.send_signal(signal.SIGINT)
            break
    lines += child.stderr.readlines()
    status = child.wait(timeout=30)
    err = "".join(lines)
    assert status in (130, -signal.SIGINT), (status, err[-1500:])
    assert "Traceback" not in err and err.strip().splitlines()[-1] == "secure3d: error: interrupted"
    assert (out / "passages.png").stat().st_size > 0, "finished files stay"
    assert not (out / "paper.md").exists(), "the table is written only when every run is done"
    assert not list(out.glob(".*.part")), "no half-written file"
