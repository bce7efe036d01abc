"""One scenario flown by each planner, side by side: :func:`fly_planners`, the text table of
:func:`comparison_table` and the figures of :func:`comparison_figures` (``secure3d simulate``,
``secure3d demo`` and the examples use them; :mod:`secure3d.simulation.campaign` re-exports them).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from secure3d.simulation.campaign_records import (
    PLANNERS,
    _fmt_ms,
    _fmt_s,
    _or_nan,
)

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.simulation.closed_loop import SimResult
    from secure3d.world.spec import Scenario

#: Columns of :func:`comparison_table`.
COMPARISON_COLUMNS = (
    "planner",
    "outcome",
    "collided",
    "time to goal",
    "min clearance",
    "take-overs",
    "replans",
    "solve median",
    "solve max",
    "real time",
)


def format_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A fixed-width text table: the header, a rule of dashes, then one line per row."""
    widths = [max(len(str(r[k])) for r in (header, *rows)) for k in range(len(header))]
    lines = [
        "  ".join(str(c).ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
        for r in (header, *rows)
    ]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def fly_planners(
    scenario: Scenario | str | os.PathLike[str],
    planners: Sequence[str] = PLANNERS,
    seed: int = 0,
    *,
    rrd: Callable[[str], str | os.PathLike[str] | None] | None = None,
    report: Callable[[SimResult], object] | None = None,
    **options: object,
) -> list[SimResult]:
    """Fly one scenario with each planner, same seed (camera noise), one NLP cache for all.

    Parameters
    ----------
    scenario : Scenario or path of a scenario YAML file.
    planners : planners to fly, in order.
    seed : simulation seed shared by every run, so the planners face the same camera noise.
    rrd : planner -> path of its Rerun recording (or None for none).
    report : called with each SimResult as soon as it is finished (e.g. to print its summary).
    **options : planner options (:class:`~secure3d.planning.problem.PlannerOptions` fields) and
        :func:`~secure3d.simulation.closed_loop.simulate`'s keyword options (``replan_latency``).
    """
    from secure3d.planning.collocation import NLPCache
    from secure3d.simulation.closed_loop import simulate

    if isinstance(scenario, (str, os.PathLike)):
        from secure3d.world.scenario import load_scenario

        scenario = load_scenario(scenario)
    cache = NLPCache()
    results = []
    for planner in planners:
        path = None if rrd is None else rrd(planner)
        result = simulate(scenario, planner, seed=seed, rrd=path, cache=cache, **options)
        if report is not None:
            report(result)
        results.append(result)
    return results


def comparison_table(
    results: Sequence[SimResult],
    reference: Mapping[str, float] | None = None,
    reference_label: str = "paper",
) -> str:
    """Closed-loop runs side by side, one row per run (``secure3d simulate`` and ``demo``).

    Parameters
    ----------
    results : SimResults, typically the same scenario flown by different planners.
    reference : planner -> time to goal (s) to quote below ours, e.g. :data:`PAPER_BLIND_CORNER`.
    reference_label : where the reference comes from (starts the quoted line).

    Returns
    -------
    str
        A fixed-width table (outcome, collided, time to goal, min clearance, take-overs, replans,
        median and max solve time, real-time factor), then the price of security when both a
        secure and a baseline run reached the goal, then the reference line.
    """
    rows = []
    for r in results:
        solves = np.asarray(r.solve_times, dtype=float)
        rows.append(
            (
                r.planner,
                r.outcome,
                "yes" if r.collided else "no",
                _fmt_s(_or_nan(r.time_to_goal)),
                _fmt_s(float(r.min_clearance), "m", 3),
                str(r.takeovers),
                str(r.replans),
                f"{_fmt_ms(float(np.median(solves)))} ms" if len(solves) else "-",
                f"{_fmt_ms(float(solves.max()))} ms" if len(solves) else "-",
                f"{r.real_time_factor:.2f}x",
            )
        )
    lines = format_table(COMPARISON_COLUMNS, rows).splitlines()
    by_planner = {r.planner: r for r in results}
    sec, base = by_planner.get("secure"), by_planner.get("baseline")
    if sec is not None and base is not None and sec.reached_goal and base.reached_goal:
        lines.append(
            f"price of security: {sec.time_to_goal / base.time_to_goal:.2f}x the baseline's time"
        )
    if reference:
        quoted = ", ".join(f"{p} {t:.2f} s" for p, t in reference.items())
        ratio = ""
        if "secure" in reference and "baseline" in reference:
            ratio = f" (ratio {reference['secure'] / reference['baseline']:.2f})"
        lines.append(f"{reference_label}: {quoted}{ratio}")
    return "\n".join(lines)


#: Events marked on the speed profiles, with their short labels.
_MARKED_EVENTS = {
    "hidden obstacle seen": "seen",
    "take-over": "take-over",
    "collision": "collision",
}
#: Events closer than this (s) share one marker, so their labels do not print over each other.
_MARKER_MERGE = 0.25


def _speed_markers(result: SimResult) -> list[tuple[float, str]]:
    markers: list[tuple[float, str]] = []
    for event in result.events:
        label = _MARKED_EVENTS.get(event.kind)
        if label is None:
            continue
        if markers and event.time - markers[-1][0] < _MARKER_MERGE:
            markers[-1] = (markers[-1][0], f"{markers[-1][1]}, {label}")
        else:
            markers.append((event.time, label))
    return markers


def comparison_figures(
    scenario: Scenario,
    results: Sequence[SimResult],
    top_down: str | os.PathLike[str] | None = None,
    speed: str | os.PathLike[str] | None = None,
) -> dict[str, Path]:
    """Figures of several runs of one scenario (atomic PNGs, folders created if missing).

    Parameters
    ----------
    scenario : the scenario flown.
    results : its runs (one per planner).
    top_down : paper-style top view: realised paths solid, each run's first plan dashed with its
        reactive sets (eq. ReactEllipse), detection points as red X, collisions as stars.
    speed : speed over time of each run, with the first sighting of a hidden obstacle, take-overs
        and collisions marked.

    Returns
    -------
    dict
        ``{"top_down": path, "speed": path}`` for the figures written.
    """
    from secure3d.dynamics import model_from_spec
    from secure3d.viz.figures import top_down_figure
    from secure3d.viz.speed_figure import speed_profile_figure
    from secure3d.world.attacks import server_claim

    written: dict[str, Path] = {}
    if top_down is not None:
        claim = server_claim(scenario)
        Path(top_down).parent.mkdir(parents=True, exist_ok=True)
        written["top_down"] = top_down_figure(
            scenario.world.bounds,
            scenario.world.boxes,
            out_path=top_down,
            true_meshes=scenario.world.meshes,
            claimed_boxes=claim.boxes,
            claimed_meshes=claim.meshes,
            hidden_names=scenario.hidden_obstacles,
            plans=[r.plans[0][1] for r in results if r.plans],
            realised_paths={r.planner: r.positions for r in results},
            detection_points={
                r.planner: r.detection_point for r in results if r.detection_point is not None
            },
            collision_points=[r.positions[-1] for r in results if r.collided],
            start=np.asarray(scenario.start.position),
            goal=np.asarray(scenario.goal.position),
            title=f"{scenario.name}: " + ", ".join(f"{r.planner} {r.outcome}" for r in results),
        )
    if speed is not None:
        Path(speed).parent.mkdir(parents=True, exist_ok=True)
        written["speed"] = speed_profile_figure(
            {r.planner: (r.times, r.speeds) for r in results},
            speed,
            markers={r.planner: _speed_markers(r) for r in results},
            speed_limit=float(model_from_spec(scenario.vehicle, scenario.camera).limits.max_speed),
            title=f"{scenario.name}: speed",
        )
    return written
