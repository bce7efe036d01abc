"""A campaign's records: one row per run (:class:`RunRecord`), its statistics, the campaign's
result and the ``summary.md`` report; the job a worker flies (:class:`_Job`).

Split from :mod:`secure3d.simulation.campaign`, which re-exports these names: the campaign's
machinery (:mod:`~secure3d.simulation.campaign_run`, ``campaign_pool``, ``campaign_store``,
``campaign_ray``) imports them from here, below the front, so no import runs in a circle.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from secure3d.errors import ConfigError
from secure3d.planning.problem import Planner
from secure3d.validation import is_int_in

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.simulation.closed_loop import SimResult
    from secure3d.world.spec import Scenario

PLANNERS = ("secure", "baseline")
#: Columns of ``campaign.csv``. Times in seconds, distances in metres; empty = not applicable.
CSV_FIELDS = (
    "variant",
    "scenario",
    "seed",
    "planner",
    "outcome",
    "collided",
    "reached_goal",
    "time_to_goal",
    "min_clearance",
    "takeovers",
    "replans",
    "solves",
    "solve_median",
    "solve_max",
    "sim_time",
    "wall_time",
    "setup_time",
    "real_time_factor",
    "detection_time",
    "plans_judged",
    "certified_first_try",
    "error",
)
#: Columns added by issue 16 (files written before them are still read).
CERTIFY_FIELDS = ("plans_judged", "certified_first_try")
CSV_NAME = "campaign.csv"
SUMMARY_NAME = "summary.md"
#: Kept for compatibility (``run_campaign``'s ``flush_every``): rows are now appended as runs end.
FLUSH_EVERY = 10
#: Outcome recorded for a run whose scenario or simulation raised a secure3d error.
ERROR_OUTCOME = "error"
#: The paper's blind-corner flight times (s) for reference (Ivanov & Campbell, Results).
PAPER_BLIND_CORNER = {"secure": 2.50, "baseline": 1.67}
PAPER_BLIND_CORNER_LABEL = "paper (planar robot, MATLAB; its baseline collides)"
#: z of the two-sided 95 % normal quantile, for the Wilson interval of a rate.
_Z95 = 1.959963984540054


# ---- one run -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunRecord:
    """One closed-loop run of a campaign: a row of ``campaign.csv``.

    Attributes
    ----------
    variant : index of the hidden-obstacle variant (0-based).
    scenario : the variant's scenario name. seed : the simulation seed (camera noise).
    planner : ``"secure"`` or ``"baseline"``.
    outcome : :attr:`SimResult.outcome <secure3d.simulation.closed_loop.SimResult.outcome>`, or
        ``"error"`` when the run raised a secure3d error (then ``error`` says why).
    time_to_goal : s, NaN when the goal was not reached. detection_time : s, NaN if never seen.
    min_clearance : smallest body-to-world distance (m).
    solve_times : wall time of every planner call of the run (s).
    sim_time, wall_time : simulated and wall-clock duration of the run (s).
    setup_time : the part of ``wall_time`` before take-off (world, camera, map, NLP compilation).
    plans_judged, certified_first_try : plan calls whose solver succeeded (so the certificate
        judged them), and how many of those certified their first solution (issue 16).
    """

    variant: int
    scenario: str
    seed: int
    planner: str
    outcome: str
    collided: bool = False
    reached_goal: bool = False
    time_to_goal: float = math.nan
    min_clearance: float = math.nan
    takeovers: int = 0
    replans: int = 0
    solve_times: tuple[float, ...] = ()
    sim_time: float = 0.0
    wall_time: float = 0.0
    setup_time: float = 0.0
    detection_time: float = math.nan
    plans_judged: int = 0
    certified_first_try: int = 0
    error: str = ""

    @classmethod
    def from_result(cls, variant: int, result: SimResult) -> RunRecord:
        """The record of a finished :class:`~secure3d.simulation.closed_loop.SimResult`."""
        return cls(
            variant=variant,
            scenario=result.scenario,
            seed=result.seed,
            planner=result.planner,
            outcome=result.outcome,
            collided=bool(result.collided),
            reached_goal=bool(result.reached_goal),
            time_to_goal=_or_nan(result.time_to_goal),
            min_clearance=float(result.min_clearance),
            takeovers=int(result.takeovers),
            replans=int(result.replans),
            solve_times=tuple(float(s) for s in result.solve_times),
            sim_time=float(result.sim_time),
            wall_time=float(result.wall_time),
            setup_time=float(result.setup_time),
            detection_time=_or_nan(result.detection_time),
            plans_judged=len(result.certify_log),
            certified_first_try=sum(1 for k, ok in result.certify_log if k == 0 and ok),
        )

    @property
    def flight_time(self) -> float:
        """Wall-clock seconds of flight: the run's wall time after its set-up."""
        return self.wall_time - self.setup_time

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second of flight (as ``SimResult.real_time_factor``)."""
        return self.sim_time / self.flight_time if self.flight_time > 0 else math.nan

    def row(self) -> dict[str, str]:
        """The CSV row (:data:`CSV_FIELDS`): numbers with 4-6 significant digits, NaN as ''."""
        solves = np.asarray(self.solve_times, dtype=float)
        return {
            "variant": str(self.variant),
            "scenario": self.scenario,
            "seed": str(self.seed),
            "planner": self.planner,
            "outcome": self.outcome,
            "collided": str(int(self.collided)),
            "reached_goal": str(int(self.reached_goal)),
            "time_to_goal": _num(self.time_to_goal),
            "min_clearance": _num(self.min_clearance),
            "takeovers": str(self.takeovers),
            "replans": str(self.replans),
            "solves": str(len(solves)),
            "solve_median": _num(float(np.median(solves)) if len(solves) else math.nan),
            "solve_max": _num(float(solves.max()) if len(solves) else math.nan),
            "sim_time": _num(self.sim_time),
            "wall_time": _num(self.wall_time),
            "setup_time": _num(self.setup_time),
            "real_time_factor": _num(self.real_time_factor),
            "detection_time": _num(self.detection_time),
            "plans_judged": str(self.plans_judged),
            "certified_first_try": str(self.certified_first_try),
            "error": " ".join(self.error.split()),
        }


def _or_nan(value: float | None) -> float:
    return math.nan if value is None else float(value)


def _num(value: float) -> str:
    return "" if not math.isfinite(value) else f"{value:.6g}"


# ---- statistics --------------------------------------------------------------------------------


def wilson_interval(successes: int, trials: int, z: float = _Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial rate (default 95 %).

    Unlike the normal approximation it stays inside [0, 1] and is informative for 0 successes:
    0 collisions in 100 runs gives an upper bound of 3.7 %, not 0.

    Parameters
    ----------
    successes, trials : int
        ``0 <= successes <= trials``; ``trials == 0`` gives ``(0, 1)``.
    """
    if trials <= 0:
        return 0.0, 1.0
    p = successes / trials
    denom = 1.0 + z * z / trials
    centre = (p + z * z / (2 * trials)) / denom
    half = z * math.sqrt(p * (1 - p) / trials + z * z / (4 * trials * trials)) / denom
    # The exact bounds at k = 0 and k = n are 0 and 1; the formula misses them by rounding.
    lo = 0.0 if successes == 0 else max(0.0, centre - half)
    hi = 1.0 if successes == trials else min(1.0, centre + half)
    return lo, hi


@dataclass(frozen=True)
class PlannerStats:
    """What a campaign measured for one planner.

    Attributes
    ----------
    runs : runs flown (errors included). errors : runs that raised a secure3d error.
    collisions, goals : runs that collided / reached the goal.
    collision_rate, goal_rate : fractions of ``runs``; collision_ci : its 95 % Wilson interval.
    mean_time, median_time : time to goal over the runs that reached it (s), NaN if none did.
    solve_p50, solve_p90, solve_max : percentiles of every planner call of every run (s).
    real_time_factor : total simulated time / total flight time of the runs (set-up apart).
    """

    planner: str
    runs: int
    errors: int
    collisions: int
    goals: int
    collision_rate: float
    collision_ci: tuple[float, float]
    goal_rate: float
    mean_time: float
    median_time: float
    solve_p50: float
    solve_p90: float
    solve_max: float
    real_time_factor: float
    first_try_rate: float = math.nan


def planner_stats(records: Sequence[RunRecord], planner: str) -> PlannerStats:
    """Aggregate the runs of ``planner`` among ``records`` (see :class:`PlannerStats`)."""
    mine = [r for r in records if r.planner == planner]
    n = len(mine)
    collisions = sum(r.collided for r in mine)
    goals = sum(r.reached_goal for r in mine)
    times = np.array([r.time_to_goal for r in mine if r.reached_goal], dtype=float)
    solves = np.array([s for r in mine for s in r.solve_times], dtype=float)
    p50, p90, smax = (
        (*np.percentile(solves, [50, 90]), solves.max()) if len(solves) else (math.nan,) * 3
    )
    flight = sum(r.flight_time for r in mine)
    judged = sum(r.plans_judged for r in mine)
    return PlannerStats(
        planner=planner,
        runs=n,
        errors=sum(r.outcome == ERROR_OUTCOME for r in mine),
        collisions=collisions,
        goals=goals,
        collision_rate=collisions / n if n else math.nan,
        collision_ci=wilson_interval(collisions, n),
        goal_rate=goals / n if n else math.nan,
        mean_time=float(times.mean()) if len(times) else math.nan,
        median_time=float(np.median(times)) if len(times) else math.nan,
        solve_p50=float(p50),
        solve_p90=float(p90),
        solve_max=float(smax),
        real_time_factor=sum(r.sim_time for r in mine) / flight if flight > 0 else math.nan,
        first_try_rate=sum(r.certified_first_try for r in mine) / judged if judged else math.nan,
    )


def price_of_security(records: Sequence[RunRecord]) -> tuple[float, int]:
    """Mean over variants of secure time to goal / baseline time to goal, and how many variants.

    Only variants that both planners flew to the goal count (a paired comparison: same world, same
    seed). The paper's blind corner gives 2.50 s / 1.67 s = 1.50. NaN and 0 without such pairs.
    """
    secure = {
        r.variant: r.time_to_goal for r in records if r.planner == Planner.SECURE and r.reached_goal
    }
    base = {
        r.variant: r.time_to_goal
        for r in records
        if r.planner == Planner.BASELINE and r.reached_goal
    }
    both = sorted(set(secure) & set(base))
    if not both:
        return math.nan, 0
    return float(np.mean([secure[v] / base[v] for v in both])), len(both)


# ---- the campaign ------------------------------------------------------------------------------


@dataclass(frozen=True)
class CampaignResult:
    """Everything a campaign produced.

    Attributes
    ----------
    base : name of the base scenario. n : number of variants. planners : planners flown.
    seed : seed of the variants (run ``i`` is simulated with seed ``seed + i``).
    records : one :class:`RunRecord` per run, variant-major, planners in the given order.
    csv_path, summary_path : the files written. wall_time : the whole campaign (s).
    settings : kind, count, workers and planner options, for the report.
    """

    base: str
    n: int
    planners: tuple[str, ...]
    seed: int
    records: tuple[RunRecord, ...]
    csv_path: Path
    summary_path: Path
    wall_time: float
    settings: Mapping[str, object] = field(default_factory=dict)

    def stats(self) -> dict[str, PlannerStats]:
        """Per-planner statistics, in the order of :attr:`planners`."""
        return {p: planner_stats(self.records, p) for p in self.planners}

    def summary_markdown(self) -> str:
        """The contents of ``summary.md``."""
        return _summary_markdown(self)


def _check_args(n: object, planners: Sequence[str], seed: object, workers: object) -> None:
    if not is_int_in(n, 1):
        raise ConfigError(f"n: must be a positive integer (got {n!r})")
    if isinstance(planners, str) or not planners:
        raise ConfigError(f"planners: must be a non-empty list of planner names (got {planners!r})")
    for p in planners:
        if p not in PLANNERS:
            raise ConfigError(f"planners: each must be one of {', '.join(PLANNERS)} (got {p!r})")
    if len(set(planners)) != len(planners):
        raise ConfigError(f"planners: names must not repeat (got {list(planners)})")
    if not is_int_in(seed, 0):
        raise ConfigError(f"seed: must be a non-negative integer (got {seed!r})")
    if workers is not None and not is_int_in(workers, 1):
        raise ConfigError(f"workers: must be a positive integer (got {workers!r})")


@dataclass(frozen=True)
class _Job:
    variant: int
    scenario: Scenario
    seed: int
    planner: str
    options: Mapping[str, object]


def error_record(job: _Job, reason: str, wall_time: float = 0.0) -> RunRecord:
    """The error row of ``job``: outcome ``error`` and the reason."""
    return RunRecord(
        variant=job.variant,
        scenario=job.scenario.name,
        seed=job.seed,
        planner=job.planner,
        outcome=ERROR_OUTCOME,
        wall_time=wall_time,
        error=reason,
    )


def _csv_text(records: Sequence[RunRecord]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CSV_FIELDS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(r.row() for r in records)
    return buffer.getvalue()


# ---- reports -----------------------------------------------------------------------------------


def _fmt_s(value: float, unit: str = "s", digits: int = 2) -> str:
    return "-" if not math.isfinite(value) else f"{value:.{digits}f} {unit}"


def _fmt_ms(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{1e3 * value:.0f}"


def _pct(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{100 * value:.1f} %"


def _summary_markdown(result: CampaignResult) -> str:
    s = result.settings
    opts = ", ".join(f"{k}={v}" for k, v in sorted(dict(s.get("options", {})).items()))
    shard = s.get("shard")
    part = f", shard {shard[0]}/{shard[1]}" if shard and tuple(shard) != (1, 1) else ""
    merged = f", merged from {s['merged']} folders" if s.get("merged") else ""
    lines = [
        f"# Campaign: {result.base}, {result.n} hidden-obstacle"
        f" variant{'' if result.n == 1 else 's'}{part}{merged}",
        "",
        f"Seed {result.seed} (variant i simulated with seed {result.seed} + i), placement"
        f" `{s.get('kind')}`, {s.get('count')} hidden obstacle(s) per variant, planner options:"
        f" {opts or 'scenario defaults'}; replans deferred by {s.get('replan_defer', 0.0)} s"
        f" (0: off); {s.get('workers')} worker(s) ({s.get('backend', 'process')}),"
        f" {result.wall_time:.1f} s wall. One row per run in `{CSV_NAME}`.",
        "",
        "| planner | runs | collisions | collision rate (95 % CI) | goal rate |"
        " mean / median time to goal | solve p50 / p90 / max (ms) | real-time factor (flight) |"
        " certified first try | errors |",
        "|---|---:|---:|---|---:|---|---|---:|---:|---:|",
    ]
    for st in result.stats().values():
        lo, hi = st.collision_ci
        lines.append(
            f"| {st.planner} | {st.runs} | {st.collisions} | {_pct(st.collision_rate)}"
            f" ({_pct(lo)} - {_pct(hi)}) | {_pct(st.goal_rate)} |"
            f" {_fmt_s(st.mean_time)} / {_fmt_s(st.median_time)} |"
            f" {_fmt_ms(st.solve_p50)} / {_fmt_ms(st.solve_p90)} / {_fmt_ms(st.solve_max)} |"
            f" {st.real_time_factor:.2f} | {_pct(st.first_try_rate)} | {st.errors} |"
        )
    ratio, pairs = price_of_security(result.records)
    if pairs:
        lines.append("")
        lines.append(
            f"Price of security: the secure planner takes {ratio:.2f}x the baseline's time to goal"
            f" (mean over the {pairs} variant(s) both reached; the paper's blind corner: "
            f"{PAPER_BLIND_CORNER['secure']:.2f} s / {PAPER_BLIND_CORNER['baseline']:.2f} s = "
            f"{PAPER_BLIND_CORNER['secure'] / PAPER_BLIND_CORNER['baseline']:.2f}x)."
        )
    elif {"secure", "baseline"} <= set(result.planners):
        lines += ["", "Price of security: no variant was flown to the goal by both planners."]
    errors = [r for r in result.records if r.outcome == ERROR_OUTCOME]
    if errors:
        lines += ["", "Errors:", ""]
        lines += [f"- variant {r.variant} / {r.planner}: {r.error}" for r in errors]
    return "\n".join(lines) + "\n"
