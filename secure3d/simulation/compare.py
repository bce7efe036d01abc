"""Runs of one scenario by each planner, side by side, as a text table (:func:`comparison_table`;
``secure3d simulate``, ``secure3d demo`` and the examples use it). Flying them with recordings is
:func:`secure3d.session.fly_planners`; their figures are :mod:`secure3d.viz.run_figures`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from secure3d.simulation.campaign_records import (
    _fmt_ms,
    _fmt_s,
    _or_nan,
)

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.simulation.closed_loop import SimResult

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
