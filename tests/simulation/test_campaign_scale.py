"""Campaigns at scale: Ray and process backends, runs.csv, resume, shards, merge, faults, failures.

Real flights, real worker processes and a real local Ray (2 CPUs); no stand-ins. The runs use a
tiny scenario (a 6 m room with one wall, 12 nodes, baseline planner: about 0.6 s per run), and the
blind corner's baseline (which collides) for the failure files.
"""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from secure3d.cli import main
from secure3d.errors import ConfigError
from secure3d.simulation.campaign import run_campaign
from secure3d.simulation.campaign_store import RUNS_NAME, merge_campaigns, read_runs

#: Columns that depend on the machine's speed, not on the run.
TIMING = {"solve_median", "solve_max", "wall_time", "setup_time", "real_time_factor", "solve_times"}
N = 4
KW = {"planners": ("baseline",), "seed": 3, "progress": False}


@pytest.fixture(scope="module")
def on_processes(tiny: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reference campaign: N variants on 2 worker processes."""
    out = tmp_path_factory.mktemp("processes")
    run_campaign(tiny, N, workers=2, out_dir=out, **KW)
    return out


def _outcomes(path: Path) -> list[dict[str, str]]:
    """Rows of a campaign.csv / runs.csv without the timing columns, sorted by run."""
    if path.name == RUNS_NAME:
        with open(path, newline="") as fh:
            next(fh)
            rows = list(csv.DictReader(fh))
    else:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
    rows = [{k: v for k, v in r.items() if k not in TIMING} for r in rows]
    return sorted(rows, key=lambda r: (int(r["variant"]), r["planner"]))


def test_ray_gives_the_same_rows_as_processes(tiny: Path, on_processes: Path, tmp_path: Path):
    result = run_campaign(tiny, N, workers=2, out_dir=tmp_path, backend="ray", **KW)
    ray_rows = _outcomes(tmp_path / "campaign.csv")
    assert ray_rows == _outcomes(on_processes / "campaign.csv")
    assert [r["variant"] for r in ray_rows] == [str(i) for i in range(N)]
    assert {r["outcome"] for r in ray_rows} <= {"reached goal", "no plan", "collided", "stopped"}
    assert result.settings["backend"] == "ray"
    # runs.csv holds the same runs (in finishing order) under its parameter line.
    params, records = read_runs(tmp_path / RUNS_NAME)
    assert params["n"] == N and params["planners"] == ["baseline"] and params["secure3d_version"]
    assert _outcomes(tmp_path / RUNS_NAME) == ray_rows
    assert len(records) == N


def test_shards_merged_equal_the_whole_campaign(tiny: Path, on_processes: Path, tmp_path: Path):
    for k in (1, 2):
        run_campaign(tiny, N, workers=1, out_dir=tmp_path / f"s{k}", shard=f"{k}/2", **KW)
    _, first = read_runs(tmp_path / "s1" / RUNS_NAME)
    assert sorted(r.variant for r in first) == [0, 2], "shard 1/2 flies the even variants"
    merged = merge_campaigns([tmp_path / "s1", tmp_path / "s2"], tmp_path / "all")
    assert _outcomes(tmp_path / "all" / "campaign.csv") == _outcomes(on_processes / "campaign.csv")
    whole = {r.variant: r for r in read_runs(on_processes / RUNS_NAME)[1]}
    assert {r.variant: r.time_to_goal for r in merged.records} == {
        v: r.time_to_goal for v, r in whole.items()
    }
    stats = merged.stats()["baseline"]
    assert stats.runs == N and stats.goals == sum(r.reached_goal for r in whole.values())
    assert (
        f"| baseline | {N} | {stats.collisions} |" in (tmp_path / "all" / "summary.md").read_text()
    )
    # A shard merged twice, or with another campaign, is refused.
    with pytest.raises(ConfigError, match="is in both"):
        merge_campaigns([tmp_path / "s1", tmp_path / "s1"], tmp_path / "twice")
    with pytest.raises(ConfigError, match="another campaign than .*: n 4 there, 1 here"):
        run_campaign(tiny, 1, workers=1, out_dir=tmp_path / "other", **KW)
        merge_campaigns([tmp_path / "s1", tmp_path / "other"], tmp_path / "x")
    with pytest.raises(ConfigError, match="no such file"):
        merge_campaigns([tmp_path / "s1", tmp_path / "nothing"], tmp_path / "x")


def _kill_variant(variant: int, times: int):
    killed: list[int] = []

    def on_start(job, pid: int) -> None:
        if job.variant == variant and len(killed) < times:
            killed.append(pid)
            os.kill(pid, signal.SIGKILL)

    return on_start, killed


@pytest.mark.parametrize("backend", ["process", "ray"])
def test_a_killed_worker_gives_an_error_row_and_the_campaign_completes(
    tiny: Path, on_processes: Path, tmp_path: Path, backend: str
):
    on_start, killed = _kill_variant(1, times=1)
    result = run_campaign(
        tiny, 3, workers=2, out_dir=tmp_path, backend=backend, retries=0, on_start=on_start, **KW
    )
    assert len(killed) == 1
    rows = {r.variant: r for r in result.records}
    assert sorted(rows) == [0, 1, 2]
    assert rows[1].outcome == "error"
    assert ("killed by signal 9" if backend == "process" else "Ray actor died") in rows[1].error
    reference = {r["variant"]: r for r in _outcomes(on_processes / "campaign.csv")}
    for v in (0, 2):
        assert rows[v].outcome == reference[str(v)]["outcome"], "the other runs are unaffected"
    assert (tmp_path / "failures" / "000001_baseline.yaml").is_file()


def test_a_crash_is_retried_on_a_fresh_worker(tiny: Path, on_processes: Path, tmp_path: Path):
    on_start, killed = _kill_variant(0, times=1)
    result = run_campaign(tiny, 1, workers=2, out_dir=tmp_path, retries=1, on_start=on_start, **KW)
    assert len(killed) == 1
    (record,) = result.records
    reference = _outcomes(on_processes / "campaign.csv")[0]
    assert record.outcome == reference["outcome"] and record.error == ""


def test_run_timeout_gives_error_rows(tiny: Path, tmp_path: Path):
    t0 = time.monotonic()
    result = run_campaign(tiny, 2, workers=1, out_dir=tmp_path, run_timeout=0.5, **KW)
    assert time.monotonic() - t0 < 30
    assert [r.outcome for r in result.records] == ["error", "error"]
    assert all("run timeout: stopped after 0.5 s" in r.error for r in result.records)
    assert "| baseline | 2 | 0 |" in result.summary_path.read_text()


def _children(pid: int) -> set[int]:
    import psutil

    try:
        return {p.pid for p in psutil.Process(pid).children(recursive=True)}
    except psutil.NoSuchProcess:
        return set()


def _rows(out: Path) -> list[tuple[int, str]]:
    path = out / RUNS_NAME
    # polled while the campaign writes it: a file just created has no complete parameter line yet
    if not path.exists() or "\n" not in path.read_text():
        return []
    return [(r.variant, r.planner) for r in read_runs(path)[1]]


@pytest.mark.slow
def test_sigint_then_resume_flies_each_run_exactly_once(tiny: Path, tmp_path: Path):
    import psutil

    n = 6
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "secure3d", "campaign", str(tiny), "-n", str(n)]
    argv += ["--planners", "baseline", "--seed", "3", "--workers", "2", "--out", str(out)]
    proc = subprocess.Popen([*argv, "--no-progress"], stderr=subprocess.PIPE, text=True)
    workers: set[int] = set()
    deadline = time.monotonic() + 120
    while len(_rows(out)) < 2 and time.monotonic() < deadline and proc.poll() is None:
        workers |= _children(proc.pid)
        time.sleep(0.05)
    assert proc.poll() is None, "the campaign ended before it could be interrupted"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "continue with --resume" in err and "interrupted" in err
    first = _rows(out)
    assert 2 <= len(first) < n
    gone = time.monotonic() + 10
    while any(psutil.pid_exists(p) for p in workers) and time.monotonic() < gone:
        time.sleep(0.1)
    assert workers and not any(psutil.pid_exists(p) for p in workers), "no worker outlives it"
    assert not (out / "campaign.csv").exists()
    # Resuming with other parameters is refused; with the same ones it flies the rest.
    bad = subprocess.run([*argv[:6], "7", *argv[7:], "--resume"], capture_output=True, text=True)
    assert bad.returncode == 2 and "holds another campaign (n 6 there, 7 here)" in bad.stderr
    done = subprocess.run([*argv, "--resume", "--no-progress"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    rows = _rows(out)
    assert rows[: len(first)] == first, "resumed rows are appended after the old ones"
    assert sorted(rows) == [(i, "baseline") for i in range(n)], "none lost, none repeated"
    assert f"| baseline | {n} |" in (out / "summary.md").read_text()


def test_workers_die_with_a_killed_parent(tiny: Path, tmp_path: Path):
    import psutil

    argv = [sys.executable, "-m", "secure3d", "campaign", str(tiny), "-n", "20", "--workers", "2"]
    argv += ["--planners", "baseline", "--out", str(tmp_path), "--no-progress"]
    proc = subprocess.Popen(argv, stderr=subprocess.DEVNULL)
    workers: set[int] = set()
    deadline = time.monotonic() + 120
    while len(_rows(tmp_path)) < 1 and time.monotonic() < deadline and proc.poll() is None:
        workers |= _children(proc.pid)
        time.sleep(0.05)
    workers |= _children(proc.pid)
    assert proc.poll() is None and len(workers) >= 2, "two workers flying"
    proc.kill()
    proc.wait()
    gone = time.monotonic() + 10
    while any(psutil.pid_exists(p) for p in workers) and time.monotonic() < gone:
        time.sleep(0.1)
    assert not any(psutil.pid_exists(p) for p in workers), "no worker outlives a SIGKILLed parent"


def test_a_failure_file_flies_the_run_again(maps_dir: Path, tmp_path: Path, capsys):
    from secure3d.simulation.closed_loop import simulate
    from secure3d.world.scenario import load_scenario

    result = run_campaign(
        maps_dir / "blind_corner.yaml",
        1,
        planners=("baseline",),
        seed=2,
        workers=1,
        out_dir=tmp_path,
        progress=False,
        nodes=20,
    )
    (record,) = result.records
    assert record.collided, "the baseline hits the hidden obstacle"
    path = tmp_path / "failures" / "000000_baseline.yaml"
    header = path.read_text().splitlines()[1]
    assert header.endswith("--planner baseline --seed 2 --replan-defer 0.5")
    scenario = load_scenario(path)
    assert scenario.name == record.scenario and scenario.planner.nodes == 20
    again = simulate(scenario, "baseline", seed=2, replan_defer=0.5)
    assert again.collided and again.outcome == record.outcome
    assert f"{again.min_clearance:.6g}" == f"{record.min_clearance:.6g}"
    assert f"{again.sim_time:.6g}" == f"{record.sim_time:.6g}"
    # The command line flies it with the seed and planner the file names.
    assert main(["simulate", str(path), "--json"]) == 0
    import json

    (flown,) = json.loads(capsys.readouterr().out)
    assert flown["planner"] == "baseline" and flown["seed"] == 2 and flown["collided"]


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--shard", "3/2"], "shard: must be K/N with 1 <= K <= N (got '3/2')"),
        (["--shard", "two"], "shard: must be K/N"),
        (["--address", "auto"], "address: only with backend 'ray'"),
        (["--run-timeout", "0"], "run_timeout: must be a positive number"),
        (["--retries", "-1"], "retries: must be a non-negative integer"),
    ],
)
def test_bad_scale_flags_are_one_line(tiny: Path, tmp_path: Path, capsys, extra, needle):
    argv = ["campaign", str(tiny), "-n", "1", "--out", str(tmp_path / "o"), *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err, err
    assert not (tmp_path / "o" / RUNS_NAME).exists()


def test_an_existing_campaign_is_not_overwritten(tiny: Path, on_processes: Path, capsys):
    before = (on_processes / RUNS_NAME).read_bytes()
    assert main(["campaign", str(tiny), "-n", "1", "--out", str(on_processes)]) == 2
    assert "exists: pass --resume" in capsys.readouterr().err
    assert (on_processes / RUNS_NAME).read_bytes() == before


# ---- the store, without flights ----------------------------------------------------------------


def _record(variant: int, planner: str = "secure"):
    from secure3d.simulation.campaign import RunRecord

    return RunRecord(
        variant=variant,
        scenario=f"s_{variant}",
        seed=variant,
        planner=planner,
        outcome="reached goal",
        reached_goal=True,
        time_to_goal=2.0 + variant,
        min_clearance=0.25,
        solve_times=(0.5, 0.125),
        sim_time=2.0,
        wall_time=3.0,
        setup_time=1.0,
    )


def test_runs_csv_round_trips_and_a_cut_last_line_is_dropped(tmp_path: Path):
    from secure3d.simulation.campaign_store import open_runs

    params = {"format": 1, "n": 3}
    runs, old = open_runs(tmp_path, params, resume=False)
    assert old == []
    for v in range(2):
        runs.append(_record(v))
    runs.close()
    path = tmp_path / RUNS_NAME
    with open(path, "a") as fh:
        fh.write("2,s_2,2,secure,reached go")  # a kill in the middle of a write
    runs, old = open_runs(tmp_path, params, resume=True)
    assert old == [_record(0), _record(1)], "whole rows come back exactly, the cut one is gone"
    runs.append(_record(2))
    runs.close()
    assert [r.variant for r in read_runs(path)[1]] == [0, 1, 2]
    with pytest.raises(ConfigError, match="holds another campaign \\(n 3 there, 4 here\\)"):
        open_runs(tmp_path, {"format": 1, "n": 4}, resume=True)
    with pytest.raises(ConfigError, match="exists: pass --resume"):
        open_runs(tmp_path, params, resume=False)
