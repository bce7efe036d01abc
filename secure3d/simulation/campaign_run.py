"""The body of :func:`secure3d.simulation.campaign.run_campaign`: variants, workers, files.

Variant ``i`` is a pure function of (base, seed, i) for every kind
(:func:`~secure3d.world.families.variant_rng`), made when its first run is started, so
``shard=(k, N)`` flies variants ``i`` with ``i % N == k - 1`` and nothing else, and no variant is
drawn up front. Each finished run is appended to ``OUT/runs.csv``
(:mod:`~secure3d.simulation.campaign_store`) as it finishes; a collided or errored run also saves
its scenario under ``OUT/failures/``. ``campaign.csv`` and ``summary.md`` are written at the end,
over every run in ``runs.csv`` (resumed ones included).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from secure3d.errors import ConfigError, Secure3DError
from secure3d.simulation.campaign_pool import InlinePool, Pool, ProcessPool, fly_job, schedule
from secure3d.simulation.campaign_records import (
    CSV_NAME,
    ERROR_OUTCOME,
    SUMMARY_NAME,
    CampaignResult,
    RunRecord,
    _check_args,
    _Job,
)
from secure3d.simulation.campaign_store import (
    RUNS_NAME,
    RunsFile,
    campaign_params,
    open_runs,
    save_failure,
    settings_of,
    sort_records,
    write_reports,
)
from secure3d.validation import is_int, is_int_in, is_real

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.world.families import Family
    from secure3d.world.spec import Scenario

__all__ = ["BACKENDS", "CampaignPlan", "execute", "parse_shard"]

log = logging.getLogger("secure3d")
BACKENDS = ("process", "ray")


def parse_shard(text: str | tuple[int, int] | None) -> tuple[int, int]:
    """``"k/N"`` (or ``(k, N)``) -> ``(k, N)`` with ``1 <= k <= N``; None -> ``(1, 1)``."""
    if text is None:
        return 1, 1
    if isinstance(text, str):
        parts = text.split("/")
        try:
            k, n = (int(p) for p in parts) if len(parts) == 2 else (0, 0)
        except ValueError:
            k, n = 0, 0
    else:
        k, n = text
    if not (is_int(k) and is_int(n)):
        k, n = 0, 0
    if not 1 <= k <= n:
        raise ConfigError(f"shard: must be K/N with 1 <= K <= N (got {text!r})")
    return k, n


def _family(kind: str, count: int, footprint: float | None = None) -> Family:
    """The family a campaign draws from (``footprint``: see ``hidden_obstacle_family``)."""
    from secure3d.world.attacks import hidden_obstacle_family
    from secure3d.world.family_registry import FAMILIES

    if kind in FAMILIES:
        if count != 1:
            raise ConfigError(f"count: family {kind!r} places its own obstacles (got {count!r})")
        return FAMILIES[kind]
    if kind not in ("auto", "corner", "forest"):
        names = ", ".join(("auto", "corner", "forest", *FAMILIES))
        raise ConfigError(f"kind: must be one of {names} (got {kind!r})")
    if not is_int_in(count, 1):
        raise ConfigError(f"count: must be a positive integer (got {count!r})")
    return hidden_obstacle_family(kind, count, footprint)  # type: ignore[arg-type]


def campaign_family(base: Scenario, kind: str, count: int, options: Mapping[str, object]) -> Family:
    """The family of a campaign over ``base``: hidden obstacles (the ``auto`` rule's and the
    ``survey`` family's) leave gaps the secure planner can pass at a standstill (its
    :func:`~secure3d.planning.problem.rest_footprint` under the campaign's planner ``options``),
    so a variant's goal is reachable by a sound planner."""
    if kind not in ("auto", "corner", "forest", "survey"):
        return _family(kind, count)
    from secure3d.planning.problem import rest_footprint
    from secure3d.world.survey_families import survey_family

    footprint = rest_footprint(base, **options)
    if kind == "survey":  # its hidden obstacle is placed by the auto rule
        return survey_family(footprint)
    return _family(kind, count, footprint)


@dataclass(frozen=True)
class CampaignPlan:
    """A checked campaign: what to fly and where (built by :func:`plan`)."""

    base: Scenario
    n: int
    planners: tuple[str, ...]
    seed: int
    kind: str
    count: int
    options: Mapping[str, object]
    replan_defer: float
    shard: tuple[int, int]
    out: Path
    #: The campaign's family (:func:`campaign_family`) and what it prepared over ``base``
    #: (:attr:`~secure3d.world.families.Family.prepare`), once, while the arguments were checked.
    family: Family = field(compare=False, repr=False)
    prepared: object = field(compare=False, repr=False)

    def params(self) -> dict[str, object]:
        """The parameters recorded in ``runs.csv``."""
        return campaign_params(
            self.base,
            self.n,
            self.seed,
            self.planners,
            self.kind,
            self.count,
            self.options,
            self.replan_defer,
            self.shard,
        )

    def variants(self) -> range:
        """This shard's variant indices."""
        k, n_shards = self.shard
        return range(k - 1, self.n, n_shards)


def _job_stream(
    plan: CampaignPlan, done: set[tuple[int, str]], scenarios: dict[int, Scenario]
) -> Iterator[_Job | RunRecord]:
    """The jobs still to fly, variant by variant; a variant that cannot be made gives error rows.
    ``scenarios`` keeps each variant's scenario until its runs are written."""
    from secure3d.world.families import variant_rng

    options = dict(plan.options, replan_defer=plan.replan_defer)
    for i in plan.variants():
        todo = [p for p in plan.planners if (i, p) not in done]
        if not todo:
            continue
        try:
            scenario = plan.family.variant(plan.prepared, plan.base, variant_rng(plan.seed, i), i)
        except Secure3DError as exc:
            for p in todo:
                yield RunRecord(
                    variant=i,
                    scenario=f"{plan.base.name}_variant_{i}",
                    seed=plan.seed + i,
                    planner=p,
                    outcome=ERROR_OUTCOME,
                    error=f"{type(exc).__name__}: {exc}",
                )
            continue
        scenarios[i] = scenario
        for p in todo:
            yield _Job(i, scenario, plan.seed + i, p, options)


def _make_pool(
    backend: str,
    workers: int,
    address: str | None,
    inline: bool,
    fly: Callable[[_Job], RunRecord] = fly_job,
) -> Pool:
    """Ray actors, this process (one worker asked for, no timeout), or worker processes."""
    if backend == "ray":
        from secure3d.simulation.campaign_ray import RayPool

        return RayPool(workers, address)
    if inline:
        return InlinePool(fly)
    return ProcessPool(workers, fly)


class _Tally:
    """Counts for the progress bar, updated in O(1) per run."""

    def __init__(self, planners: Sequence[str]) -> None:
        self.collided = dict.fromkeys(planners, 0)
        self.runs = dict.fromkeys(planners, 0)
        self.errors = 0

    def add(self, record: RunRecord) -> str:
        self.runs[record.planner] = self.runs.get(record.planner, 0) + 1
        self.collided[record.planner] = self.collided.get(record.planner, 0) + record.collided
        self.errors += record.outcome == ERROR_OUTCOME
        parts = [f"{p} {self.collided[p]}/{self.runs[p]} collided" for p in self.runs]
        return ", ".join(parts) + (f", {self.errors} errors" if self.errors else "")


@dataclass(frozen=True)
class Execution:
    """How to run a plan: the backend, its workers and the fault limits.

    Attributes
    ----------
    backend : ``"process"`` (worker processes on this machine) or ``"ray"`` (Ray actors; a local
        Ray, or the cluster at ``address``).
    workers : workers (default: the CPUs, or the Ray cluster's; at most one per run). With the
        process backend, 1 worker and no ``run_timeout`` fly in this process. Each worker keeps
        one NLP cache for all its runs.
    address : the Ray cluster's address (backend ``"ray"`` only).
    run_timeout : wall seconds a run may take (set-up included) before its worker is killed and
        the run becomes an error row.
    retries : times a run whose worker died is flown again before it becomes an error row.
    resume : continue the campaign in ``out_dir``: fly exactly the (variant, planner) runs missing
        from its ``runs.csv`` (refused if its parameters differ). Without it, an existing
        ``runs.csv`` is refused.
    progress : show a tqdm progress bar on stderr (runs/s, collisions so far, ETA).
    on_start : called with (job, worker pid) as each run starts.
    fly : flies one job into its row (default :func:`~secure3d.simulation.campaign_pool.fly_job`,
        the closed loop); a module-level function, since worker processes receive it by name.
        Tests pass a stand-in to check the bookkeeping without flying.
    """

    backend: str = "process"
    workers: int | None = None
    address: str | None = None
    run_timeout: float | None = None
    retries: int = 1
    resume: bool = False
    progress: bool = True
    on_start: Callable[[_Job, int], object] | None = None
    fly: Callable[[_Job], RunRecord] = fly_job


def _check_execution(ex: Execution) -> None:
    if ex.backend not in BACKENDS:
        raise ConfigError(f"backend: must be one of {', '.join(BACKENDS)} (got {ex.backend!r})")
    if ex.address is not None and ex.backend != "ray":
        raise ConfigError("address: only with backend 'ray' (--backend ray)")
    t = ex.run_timeout
    if t is not None and (not is_real(t) or not t > 0):
        raise ConfigError(f"run_timeout: must be a positive number of seconds (got {t!r})")
    r = ex.retries
    if not is_int_in(r, 0):
        raise ConfigError(f"retries: must be a non-negative integer (got {r!r})")


def plan_campaign(
    base: Scenario | str | os.PathLike[str],
    n: int,
    planners: Sequence[str],
    seed: int,
    out_dir: str | os.PathLike[str],
    kind: str,
    count: int,
    replan_defer: float | None,
    shard: str | tuple[int, int] | None,
    options: Mapping[str, object],
) -> CampaignPlan:
    """Check every argument (before any run) and load the base scenario."""
    from secure3d.planning.problem import problem_from_scenario
    from secure3d.simulation.closed_loop import replan_defer_for

    planners = tuple(planners)
    _check_args(n, planners, seed, None)
    shard_kn = parse_shard(shard)
    _family(kind, count)
    defer = replan_defer_for(replan_defer, 0.0, ConfigError)
    if isinstance(base, (str, os.PathLike)):
        from secure3d.world.scenario import load_scenario

        base = load_scenario(base)
    # Bad planner options, or a family the base cannot take (a deadend on a single route, a 3D
    # family on a planar robot), would otherwise surface as one error row per run.
    problem_from_scenario(base, **options)
    family = campaign_family(base, kind, count, options)
    prepared = family.prepare(base)
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"out_dir: cannot create {str(out)!r}: {exc.strerror or exc}") from None
    return CampaignPlan(
        base, n, planners, seed, kind, count, dict(options), defer, shard_kn, out, family, prepared
    )


def execute(plan: CampaignPlan, ex: Execution) -> CampaignResult:
    """Fly ``plan`` as ``ex`` says; see :func:`~secure3d.simulation.campaign.run_campaign`."""
    _check_execution(ex)
    wall0 = time.perf_counter()
    workers = ex.workers
    if workers is None:
        from secure3d.simulation.campaign_ray import default_workers

        workers = default_workers(ex.address) if ex.backend == "ray" else os.cpu_count() or 1
    runs, old = open_runs(plan.out, plan.params(), ex.resume)
    done = {(r.variant, r.planner) for r in old}
    todo = sum(1 for i in plan.variants() for p in plan.planners if (i, p) not in done)
    inline = ex.backend == "process" and workers == 1 and ex.run_timeout is None
    workers = max(1, min(workers, todo or 1))
    new: list[RunRecord] = []
    try:
        if todo:
            pool = _make_pool(ex.backend, workers, ex.address, inline, ex.fly)
            try:
                new = _fly_all(plan, ex, pool, runs, done, todo)
            finally:
                pool.close()
    except BaseException:
        log.info("stopped: finished runs are in %s; continue with --resume", plan.out / RUNS_NAME)
        raise
    finally:
        runs.close()
    result = CampaignResult(
        base=plan.base.name,
        n=plan.n,
        planners=plan.planners,
        seed=plan.seed,
        records=tuple(sort_records([*old, *new], plan.planners)),
        csv_path=plan.out / CSV_NAME,
        summary_path=plan.out / SUMMARY_NAME,
        wall_time=time.perf_counter() - wall0,
        settings={
            **settings_of(plan.params(), workers),
            "backend": ex.backend,
            "resumed": len(old),
        },
    )
    write_reports(plan.out, result)
    return result


def _save_failure(plan: CampaignPlan, scenario: Scenario, record: RunRecord) -> None:
    """Save a failure file; a file that cannot be written is logged, the campaign goes on."""
    try:
        save_failure(plan.out, scenario, record, plan.options, plan.replan_defer)
    except (Secure3DError, OSError) as exc:
        log.warning(
            "variant %d / %s: failure file not saved: %s", record.variant, record.planner, exc
        )


def _fly_all(
    plan: CampaignPlan,
    ex: Execution,
    pool: Pool,
    runs: RunsFile,
    done: set[tuple[int, str]],
    todo: int,
) -> list[RunRecord]:
    """Stream every remaining run through ``pool`` into ``runs.csv``, with a progress bar."""
    from tqdm import tqdm

    scenarios: dict[int, Scenario] = {}
    left = {i: sum((i, p) not in done for p in plan.planners) for i in plan.variants()}
    tally = _Tally(plan.planners)
    new: list[RunRecord] = []
    bar = tqdm(total=todo, desc=plan.base.name, unit="run", disable=not ex.progress, leave=False)
    try:
        stream = _job_stream(plan, done, scenarios)
        for _job, record in schedule(pool, stream, ex.run_timeout, ex.retries, ex.on_start):
            runs.append(record)
            new.append(record)
            scenario = scenarios.get(record.variant)
            if scenario is not None and (record.collided or record.outcome == ERROR_OUTCOME):
                _save_failure(plan, scenario, record)
            left[record.variant] -= 1
            if left[record.variant] == 0:
                scenarios.pop(record.variant, None)
            bar.set_postfix_str(tally.add(record), refresh=False)
            bar.update(1)
    finally:
        bar.close()
    return new
