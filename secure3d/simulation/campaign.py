"""Planners compared in closed loop: one scenario side by side, and randomised campaigns.

A *campaign* is the empirical side of the paper's safety theorem (Proof of Safety): the secure
planner must never collide, whatever the server hid, while the baseline's collision rate is the
price of trusting the map. :func:`run_campaign` derives ``n`` variants of a base scenario with
hidden obstacles placed where they matter (:func:`~secure3d.world.attacks.hidden_obstacle_family`:
variant ``i`` is a pure function of (base, seed, i)), flies each variant with every planner
(:func:`~secure3d.simulation.closed_loop.simulate`, the paper's Algorithm 1) in worker processes
or on Ray (:mod:`~secure3d.simulation.campaign_pool`, :mod:`~secure3d.simulation.campaign_ray`),
and writes into its folder

- ``runs.csv``: one row per run, appended as the run finishes, after a parameter line
  (:mod:`~secure3d.simulation.campaign_store`): the record ``--resume`` and ``campaign-merge``
  read back;
- ``campaign.csv``: the same rows sorted variant-major (:data:`CSV_FIELDS`), so the file is the
  same for the same seed whatever the backend or the number of workers (apart from the timing
  columns);
- ``summary.md``: per planner the collision rate (with a 95 % Wilson interval), the goal rate, the
  time to goal, solve-time percentiles and the real-time factor, plus the price of security
  (DESIGN.md §6);
- ``failures/<variant>_<planner>.yaml``: the scenario of every collided or errored run.

This module holds the records, statistics and reports; the machinery lives in
:mod:`~secure3d.simulation.campaign_run`.

:func:`comparison_table` presents one scenario's runs by each planner side by side (flown by
:func:`secure3d.session.fly_planners`, drawn by :mod:`secure3d.viz.run_figures`).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from secure3d import outputs
from secure3d.errors import ConfigError
from secure3d.simulation.campaign_pool import fly_job
from secure3d.simulation.campaign_records import (
    CERTIFY_FIELDS,
    CSV_FIELDS,
    CSV_NAME,
    ERROR_OUTCOME,
    FLUSH_EVERY,
    PAPER_BLIND_CORNER,
    PAPER_BLIND_CORNER_LABEL,
    PLANNERS,
    SUMMARY_NAME,
    CampaignResult,
    PlannerStats,
    RunRecord,
    _check_args,
    _Job,
    error_record,
    planner_stats,
    price_of_security,
    wilson_interval,
)
from secure3d.simulation.compare import (
    COMPARISON_COLUMNS,
    comparison_table,
    format_table,
)
from secure3d.validation import is_int_in

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.world.spec import Scenario

__all__ = [
    "CERTIFY_FIELDS",
    "COMPARISON_COLUMNS",
    "CSV_FIELDS",
    "CSV_NAME",
    "ERROR_OUTCOME",
    "FLUSH_EVERY",
    "PAPER_BLIND_CORNER",
    "PAPER_BLIND_CORNER_LABEL",
    "PLANNERS",
    "SUMMARY_NAME",
    "CampaignResult",
    "PlannerStats",
    "RunRecord",
    "atomic_write_text",
    "comparison_table",
    "error_record",
    "format_table",
    "planner_stats",
    "price_of_security",
    "run_campaign",
    "wilson_interval",
]


def run_campaign(
    base: Scenario | str | os.PathLike[str],
    n: int,
    planners: Sequence[str] = PLANNERS,
    seed: int = 0,
    workers: int | None = None,
    out_dir: str | os.PathLike[str] = "out/campaign",
    progress: bool = True,
    *,
    kind: str = "auto",
    count: int = 1,
    flush_every: int = FLUSH_EVERY,
    replan_defer: float | None = None,
    backend: str = "process",
    address: str | None = None,
    resume: bool = False,
    shard: str | tuple[int, int] | None = None,
    run_timeout: float | None = None,
    retries: int = 1,
    on_start: Callable[[_Job, int], object] | None = None,
    fly: Callable[[_Job], RunRecord] = fly_job,
    **options: object,
) -> CampaignResult:
    """Fly ``n`` randomised hidden-obstacle variants of ``base`` with each planner.

    Parameters
    ----------
    base : Scenario or path of a scenario YAML file.
    n : number of variants (each flown once per planner).
    planners : subset of ``("secure", "baseline")``, in the order rows are sorted.
    seed : seeds the variants: variant ``i`` is a pure function of (base, seed, i)
        (:func:`~secure3d.world.families.variant_rng`) and is simulated with seed ``seed + i`` by
        every planner, so the planners are compared on the same world and the same camera noise.
    workers, progress, backend, address, resume, run_timeout, retries, on_start, fly : how the
        runs are flown: the fields of :class:`~secure3d.simulation.campaign_run.Execution`.
    out_dir : folder for ``runs.csv``, ``campaign.csv``, ``summary.md`` and ``failures/``.
    kind, count : placement and number of hidden obstacles per variant (``auto``, ``corner``,
        ``forest``: :func:`~secure3d.world.attacks.hidden_obstacle_family`), or the name of a
        family in :data:`~secure3d.world.family_registry.FAMILIES` (``count`` must then be 1).
    flush_every : kept for compatibility; every run is now appended to ``runs.csv`` as it ends.
    replan_defer : :func:`~secure3d.simulation.closed_loop.simulate`'s ``replan_defer`` for every
        run (s; None: its default, 0.5 s; 0: replan at once).
    shard : ``"k/N"``: fly only variants ``i`` with ``i % N == k - 1`` (combine the shards'
        folders with :func:`~secure3d.simulation.campaign_store.merge_campaigns`).
    **options : planner options for every run (:class:`~secure3d.planning.problem.PlannerOptions`
        fields, ``reactive_family``, ``controller``).

    Returns
    -------
    CampaignResult
        Over every run in ``runs.csv`` (resumed ones included).

    Raises
    ------
    ConfigError
        Bad arguments or planner options (checked before any run), ``out_dir`` cannot be created,
        ``runs.csv`` exists without ``resume`` or holds another campaign.
    ScenarioError
        The base scenario is invalid or has no path to place obstacles on.
    """
    from secure3d.simulation.campaign_run import Execution, execute, plan_campaign

    _check_args(n, planners, seed, workers)
    if not is_int_in(flush_every, 1):
        raise ConfigError(f"flush_every: must be a positive integer (got {flush_every!r})")
    plan = plan_campaign(
        base, n, planners, seed, out_dir, kind, count, replan_defer, shard, options
    )
    execution = Execution(
        backend=backend,
        workers=workers,
        address=address,
        run_timeout=run_timeout,
        retries=retries,
        resume=resume,
        progress=progress,
        on_start=on_start,
        fly=fly,
    )
    return execute(plan, execution)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` atomically (:func:`secure3d.outputs.atomic_write_text`) into an
    existing folder."""
    path = Path(path)
    if not path.parent.is_dir():
        raise ConfigError(f"path: folder {str(path.parent)!r} does not exist")
    return outputs.atomic_write_text(path, text)
