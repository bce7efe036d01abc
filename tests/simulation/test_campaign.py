"""Campaigns: the CSV matches independent re-runs, statistics are right, files are atomic.

The flights use a tiny scenario (a 6 m room with one wall, 12 nodes, baseline planner: ~1 s per
run). The bookkeeping (ordering, flushing, interruption, validation) is tested with a stand-in for
the per-run function, so it costs no simulation at all.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

from secure3d.errors import ConfigError
from secure3d.simulation import campaign
from secure3d.simulation.campaign import (
    CSV_FIELDS,
    RunRecord,
    atomic_write_text,
    comparison_table,
    planner_stats,
    price_of_security,
    run_campaign,
    wilson_interval,
)
from secure3d.simulation.campaign_store import RUNS_NAME, read_runs
from secure3d.simulation.closed_loop import SimEvent, simulate
from secure3d.viz.run_figures import _speed_markers
from secure3d.world import load_scenario
from secure3d.world.attacks import hidden_obstacle_family
from secure3d.world.families import family_variants


def _read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        assert tuple(reader.fieldnames) == CSV_FIELDS
        return list(reader)


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".part"))


# ---- real flights ------------------------------------------------------------------------------


def test_csv_rows_match_independent_simulations(tiny: Path, tmp_path: Path) -> None:
    seed = 7
    result = run_campaign(
        tiny, 2, planners=("baseline",), seed=seed, workers=1, out_dir=tmp_path, progress=False
    )
    rows = _read_csv(result.csv_path)
    variants = family_variants(hidden_obstacle_family(), load_scenario(tiny), 2, seed)
    assert len(rows) == len(result.records) == 2
    for i, (row, variant) in enumerate(zip(rows, variants, strict=True)):
        sim = simulate(variant, "baseline", seed=seed + i)
        where = f"variant {i}"
        assert row["variant"] == str(i) and row["seed"] == str(seed + i), where
        assert row["scenario"] == variant.name == sim.scenario, where
        assert row["outcome"] == sim.outcome, where
        assert row["collided"] == str(int(sim.collided)), where
        assert row["reached_goal"] == str(int(sim.reached_goal)), where
        assert int(row["takeovers"]) == sim.takeovers and int(row["replans"]) == sim.replans
        assert int(row["solves"]) == len(sim.solve_times), where
        # The CSV keeps 6 significant digits.
        np.testing.assert_allclose(
            float(row["min_clearance"]), sim.min_clearance, rtol=1e-5, err_msg=where
        )
        np.testing.assert_allclose(float(row["sim_time"]), sim.sim_time, rtol=1e-5, err_msg=where)
        if sim.reached_goal:
            np.testing.assert_allclose(
                float(row["time_to_goal"]), sim.time_to_goal, rtol=1e-5, err_msg=where
            )
        else:
            assert row["time_to_goal"] == "", where
    summary = result.summary_path.read_text()
    assert summary.startswith("# Campaign: tiny_room, 2 hidden-obstacle variants")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["campaign.csv", "runs.csv", "summary.md"]


@pytest.mark.slow
def test_worker_processes_give_the_same_rows(tiny: Path, tmp_path: Path) -> None:
    kwargs = {"planners": ("secure", "baseline"), "seed": 1, "progress": False}
    one = run_campaign(tiny, 2, workers=1, out_dir=tmp_path / "one", **kwargs)
    two = run_campaign(tiny, 2, workers=2, out_dir=tmp_path / "two", **kwargs)
    timing = {"solve_median", "solve_max", "wall_time", "setup_time", "real_time_factor"}
    strip = [
        [{k: v for k, v in r.items() if k not in timing} for r in _read_csv(x.csv_path)]
        for x in (one, two)
    ]
    assert strip[0] == strip[1]
    assert [r["planner"] for r in strip[0]] == ["secure", "baseline"] * 2


# ---- bookkeeping, with a stand-in for the flights ----------------------------------------------


@dataclass
class FakeFlights:
    """Stands in for ``campaign._fly``: a record per job; optionally Ctrl-C at job ``stop_at``.
    ``runs_seen``: rows in ``runs.csv`` as each job starts."""

    out_dir: Path
    stop_at: int | None = None
    calls: list[tuple[int, str]] = field(default_factory=list)
    runs_seen: list[int] = field(default_factory=list)

    def __call__(self, job: campaign._Job) -> RunRecord:
        if len(self.calls) == self.stop_at:
            raise KeyboardInterrupt
        self.runs_seen.append(len(read_runs(self.out_dir / RUNS_NAME)[1]))
        self.calls.append((job.variant, job.planner))
        collided = job.planner == "baseline" and job.variant % 2 == 1
        return RunRecord(
            variant=job.variant,
            scenario=job.scenario.name,
            seed=job.seed,
            planner=job.planner,
            outcome="collided" if collided else "reached goal",
            collided=collided,
            reached_goal=not collided,
            time_to_goal=math.nan if collided else 2.0 + job.variant,
            min_clearance=0.1,
            solve_times=(0.01, 0.03),
            sim_time=2.0,
            wall_time=4.0,
        )


def test_rows_are_sorted_and_appended_as_runs_finish(tiny: Path, tmp_path: Path) -> None:
    fake = FakeFlights(tmp_path)
    result = run_campaign(
        tiny, 3, seed=4, workers=1, out_dir=tmp_path, progress=False, flush_every=2, fly=fake
    )
    rows = _read_csv(result.csv_path)
    expected = [(v, p) for v in range(3) for p in ("secure", "baseline")]
    assert fake.calls == expected
    assert [(int(r["variant"]), r["planner"]) for r in rows] == expected
    assert [int(r["seed"]) for r in rows] == [4, 4, 5, 5, 6, 6]
    # runs.csv holds every run finished so far, whenever a run starts.
    assert fake.runs_seen == [0, 1, 2, 3, 4, 5]
    assert len(read_runs(tmp_path / RUNS_NAME)[1]) == 6
    summary = result.summary_path.read_text()
    assert "| secure | 3 | 0 | 0.0 %" in summary
    assert "| baseline | 3 | 1 | 33.3 %" in summary
    # Variants 0 and 2 reached the goal with both planners, in the same time.
    assert "takes 1.00x the baseline's time to goal (mean over the 2 variant(s)" in summary


def test_interrupted_campaign_keeps_its_finished_runs(tiny: Path, tmp_path: Path) -> None:
    fake = FakeFlights(tmp_path, stop_at=3)
    with pytest.raises(KeyboardInterrupt):
        run_campaign(tiny, 4, workers=1, out_dir=tmp_path, progress=False, fly=fake)
    assert not (tmp_path / campaign.CSV_NAME).exists()
    assert not (tmp_path / campaign.SUMMARY_NAME).exists()
    assert _leftovers(tmp_path) == []
    _, saved = read_runs(tmp_path / RUNS_NAME)
    assert [(r.variant, r.planner) for r in saved] == [
        (0, "secure"),
        (0, "baseline"),
        (1, "secure"),
    ]


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"n": 0}, "n: must be a positive integer"),
        ({"n": 1, "planners": ("secure", "fast")}, "planners: each must be one of"),
        ({"n": 1, "planners": ("baseline", "baseline")}, "must not repeat"),
        ({"n": 1, "planners": ()}, "planners: must be a non-empty"),
        ({"n": 1, "workers": 0}, "workers: must be a positive integer"),
        ({"n": 1, "seed": -1}, "seed: must be a non-negative integer"),
        ({"n": 1, "flush_every": 0}, "flush_every"),
        ({"n": 1, "replan_defer": -0.5}, "replan_defer"),
        ({"n": 1, "nodes": 2}, "nodes"),
        ({"n": 1, "warp_drive": True}, "unknown planner option"),
    ],
)
def test_bad_arguments_fail_before_any_run(
    kwargs: dict, needle: str, tiny: Path, tmp_path: Path
) -> None:
    fake = FakeFlights(tmp_path)
    with pytest.raises(ConfigError, match=needle):
        run_campaign(tiny, out_dir=tmp_path, progress=False, fly=fake, **kwargs)
    assert fake.calls == []


# ---- statistics --------------------------------------------------------------------------------


@pytest.mark.parametrize(("k", "n"), [(0, 10), (0, 100), (3, 20), (7, 7), (50, 100)])
def test_wilson_bounds_solve_the_score_equation(k: int, n: int) -> None:
    # Independently: the bounds are the roots in p of (k/n - p)^2 = z^2 p (1 - p) / n.
    z = 1.959963984540054
    phat = k / n
    roots = np.sort(np.roots([1 + z * z / n, -(2 * phat + z * z / n), phat * phat]).real)
    lo, hi = wilson_interval(k, n)
    np.testing.assert_allclose([lo, hi], roots, atol=1e-12, err_msg=f"{k}/{n}")
    assert lo <= phat <= hi


def test_wilson_zero_of_a_hundred_is_not_zero() -> None:
    lo, hi = wilson_interval(0, 100)
    assert lo == 0.0 and 0.036 < hi < 0.038, "0 collisions in 100 runs: upper bound ~3.7 %"
    assert wilson_interval(0, 0) == (0.0, 1.0)


def _record(
    variant: int, planner: str, t: float | None, solves: tuple[float, ...] = ()
) -> RunRecord:
    return RunRecord(
        variant=variant,
        scenario=f"v{variant}",
        seed=variant,
        planner=planner,
        outcome="reached goal" if t is not None else "collided",
        collided=t is None,
        reached_goal=t is not None,
        time_to_goal=math.nan if t is None else t,
        solve_times=solves,
        sim_time=2.0,
        wall_time=1.25,
        setup_time=0.25,  # the real-time factor counts flight only: 2.0 s / 1.0 s
    )


def test_planner_stats_by_hand() -> None:
    records = [
        _record(0, "secure", 3.0, (0.1, 0.2)),
        _record(1, "secure", 5.0, (0.3,)),
        _record(2, "secure", 4.0, (0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)),
        _record(0, "baseline", 2.0),
        _record(1, "baseline", None),
    ]
    st = planner_stats(records, "secure")
    assert (st.runs, st.collisions, st.goals, st.errors) == (3, 0, 3, 0)
    np.testing.assert_allclose([st.mean_time, st.median_time], [4.0, 4.0], atol=1e-12)
    # Ten solves 0.1 .. 1.0: median 0.55, 90th percentile (linear) 0.91, max 1.0.
    np.testing.assert_allclose(
        [st.solve_p50, st.solve_p90, st.solve_max], [0.55, 0.91, 1.0], atol=1e-12
    )
    np.testing.assert_allclose(st.real_time_factor, 2.0, atol=1e-12)
    base = planner_stats(records, "baseline")
    assert (base.runs, base.collisions, base.goals) == (2, 1, 1)
    np.testing.assert_allclose([base.collision_rate, base.goal_rate], [0.5, 0.5], atol=1e-12)
    assert math.isnan(base.solve_p50), "no solves recorded"
    ratio, pairs = price_of_security(records)
    assert pairs == 1 and ratio == pytest.approx(1.5), "only variant 0 reached the goal twice"


# ---- presentation ------------------------------------------------------------------------------


@dataclass
class StandInRun:
    """The SimResult attributes the comparison table reads."""

    planner: str
    reached_goal: bool
    time_to_goal: float | None
    collided: bool = False
    min_clearance: float = 0.05
    takeovers: int = 0
    replans: int = 0
    solve_times: tuple[float, ...] = (0.2, 0.4, 0.3)
    real_time_factor: float = 1.0
    events: tuple[SimEvent, ...] = ()

    @property
    def outcome(self) -> str:
        return "collided" if self.collided else "reached goal"


def test_comparison_table_rows_and_price_of_security() -> None:
    runs = [StandInRun("secure", True, 3.0), StandInRun("baseline", True, 2.4)]
    text = comparison_table(runs, {"secure": 2.5, "baseline": 1.67}, "paper")
    lines = text.splitlines()
    assert lines[0].split()[:2] == ["planner", "outcome"]
    assert lines[2].startswith("secure") and "3.00 s" in lines[2] and "300 ms" in lines[2]
    assert "price of security: 1.25x" in text
    assert lines[-1] == "paper: secure 2.50 s, baseline 1.67 s (ratio 1.50)"
    crashed = [StandInRun("secure", True, 3.0), StandInRun("baseline", False, None, collided=True)]
    assert "price of security" not in comparison_table(crashed)


def test_speed_markers_merge_simultaneous_events() -> None:
    events = (
        SimEvent(1.20, "hidden obstacle seen"),
        SimEvent(1.27, "take-over"),
        SimEvent(1.5, "plan"),
        SimEvent(3.0, "collision"),
    )
    run = StandInRun("baseline", False, None, collided=True, events=events)
    assert _speed_markers(run) == [(1.20, "seen, take-over"), (3.0, "collision")]


def test_atomic_write_keeps_the_old_file_on_failure(tmp_path: Path) -> None:
    path = tmp_path / "table.csv"
    atomic_write_text(path, "old\n")
    with pytest.raises(TypeError):
        atomic_write_text(path, 12345)  # type: ignore[arg-type]
    assert path.read_text() == "old\n"
    assert _leftovers(tmp_path) == []
    with pytest.raises(ConfigError, match="does not exist"):
        atomic_write_text(tmp_path / "missing" / "x.csv", "x")


def test_a_campaign_flies_a_registered_family(maps_dir, tmp_path):
    """`--kind thin` draws the thin-obstacle family: variant i is a pure function of (base, seed,
    i), so a 2-variant campaign flies the first two variants of a 3-variant draw."""
    from secure3d.world.families import family_variants
    from secure3d.world.family_registry import FAMILIES
    from secure3d.world.scenario import load_scenario

    base = load_scenario(maps_dir / "blind_corner.yaml")
    three = family_variants(FAMILIES["thin"], base, 3, seed=5)
    result = run_campaign(
        base,
        2,
        planners=("secure",),
        seed=5,
        workers=1,
        out_dir=tmp_path,
        progress=False,
        kind="thin",
        nodes=20,
    )
    assert [r.scenario for r in result.records] == [v.name for v in three[:2]]
    assert three[0].world.boxes != base.world.boxes
    assert not any(r.collided for r in result.records)
    with pytest.raises(ConfigError, match="count"):
        run_campaign(base, 1, workers=1, out_dir=tmp_path, progress=False, kind="thin", count=2)


def test_runs_files_carry_the_certificate_counts_and_older_files_still_read(tmp_path):
    """Issue 16: each run records its plan calls the certificate judged and how many certified
    their first solution; a runs.csv written before those columns reads back with zeros."""
    import csv
    import io

    from secure3d.simulation.campaign import RunRecord
    from secure3d.simulation.campaign_store import (
        RUNS_FIELDS,
        _header_line,
        _row_values,
        read_runs,
    )

    rec = RunRecord(0, "x", 0, "secure", "reached goal", plans_judged=4, certified_first_try=3)
    new = tmp_path / "new.csv"
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows([RUNS_FIELDS, _row_values(rec)])
    new.write_text(_header_line({"n": 1}) + buf.getvalue())
    _, [back] = read_runs(new)
    assert (back.plans_judged, back.certified_first_try) == (4, 3)
    keep = [
        i for i, f in enumerate(RUNS_FIELDS) if f not in ("plans_judged", "certified_first_try")
    ]
    rows = [[row[i] for i in keep] for row in (RUNS_FIELDS, _row_values(rec))]
    old = tmp_path / "old.csv"
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerows(rows)
    old.write_text(_header_line({"n": 1}) + buf.getvalue())
    _, [legacy] = read_runs(old)
    assert (legacy.plans_judged, legacy.certified_first_try) == (0, 0)
    assert legacy.outcome == "reached goal"
    bad = tmp_path / "bad.csv"
    bad.write_text(_header_line({"n": 1}) + "variant,nonsense\n")
    with pytest.raises(ConfigError, match="unexpected columns"):
        read_runs(bad)


def _gaps_beside(base, variant) -> list[float]:
    """Gaps between each added hidden box and the obstacles beside it (not under or over it)."""
    import numpy as np

    from secure3d.world.truth import true_obstacles

    lo0, hi0 = true_obstacles(base).aabbs()
    gaps = []
    for box in variant.world.boxes[len(base.world.boxes) :]:
        lo, hi = np.array(box.lo), np.array(box.hi)
        beside = (hi0[:, 2] > lo[2] + 1e-9) & (lo0[:, 2] < hi[2] - 1e-9)
        per_axis = np.maximum(0.0, np.maximum(lo0[beside] - hi, lo - hi0[beside]))
        gaps += [float(g) for g in np.linalg.norm(per_axis, axis=1) if g > 0.0]
    return gaps


def test_hidden_obstacles_leave_gaps_the_secure_robot_can_pass_at_rest() -> None:
    """A quadrotor's fitted reactive set at rest is ~0.1 m wider than its body: campaign variants
    leave every gap wide enough for it (after a map voxel on each side), not just for the body."""
    from secure3d.planning.problem import rest_footprint
    from secure3d.simulation.campaign_run import _family, campaign_family
    from secure3d.world import load_scenario
    from secure3d.world.families import family_variants

    base = load_scenario("blind_corner_quadrotor")
    footprint = rest_footprint(base)
    assert footprint > base.vehicle.body_radius + base.planner.margin + 0.05
    need = 2 * footprint + 2 * base.server_map.resolution
    old = family_variants(_family("auto", 1), base, 12, seed=0)
    new = family_variants(campaign_family(base, "auto", 1, {}), base, 12, seed=0)
    assert min(g for v in old for g in _gaps_beside(base, v)) < need, "the body rule alone"
    assert min(g for v in new for g in _gaps_beside(base, v)) >= need - 1e-9


def test_the_rest_footprint_is_the_reactive_set_at_rest_plus_the_margin() -> None:
    import numpy as np

    from secure3d.planning.problem import problem_from_scenario, rest_footprint
    from secure3d.world import load_scenario

    base = load_scenario("blind_corner")
    problem = problem_from_scenario(base)
    _, M = problem.family.ellipsoid(problem.x0)
    want = float(np.linalg.eigvalsh(M).max()) + problem.options.margin
    assert abs(rest_footprint(base) - want) < 1e-12
    assert abs(rest_footprint(base, margin=0.1) - (want + 0.1 - problem.options.margin)) < 1e-12
    with pytest.raises(ConfigError, match="margin"):
        rest_footprint(base, margin=-1.0)


@pytest.mark.parametrize("footprint", [0.0, -0.3, 7.0, True, "0.3", float("nan")])
def test_a_bad_footprint_is_refused_naming_the_value(footprint) -> None:
    from secure3d.errors import ScenarioError
    from secure3d.world.attacks import hidden_obstacle_family

    with pytest.raises(ScenarioError, match=r"footprint: .*got"):
        hidden_obstacle_family("auto", 1, footprint)
