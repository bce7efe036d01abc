"""Helpers shared by the numbered examples: their command line and the closed-loop comparison.

Not an example itself. Each script puts its own folder on ``sys.path`` and imports from here, so
``python examples/NN_name.py`` works from the repository root and the smoke tests can load the
scripts by file path.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Mapping
from pathlib import Path

from secure3d.session import fly_planners
from secure3d.simulation.closed_loop import SimResult
from secure3d.simulation.compare import comparison_table
from secure3d.viz.run_figures import comparison_figures
from secure3d.world import Scenario

#: The scenario files the examples load.
MAPS = Path(__file__).resolve().parents[1] / "maps"
#: Help of ``--quick`` in most examples.
QUICK_HELP = "20 collocation nodes instead of 40"


def example_parser(doc: str, *, quick_help: str = QUICK_HELP) -> argparse.ArgumentParser:
    """The options every example has: ``--out`` and ``--quick``.

    Parameters
    ----------
    doc : the example's module docstring; its first line describes the command.
    quick_help : help text of ``--quick``.

    Returns
    -------
    argparse.ArgumentParser
        A parser the caller may extend with its own options.
    """
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/examples"), help="output folder")
    parser.add_argument("--quick", action="store_true", help=quick_help)
    return parser


def parse_example_args(
    doc: str, argv: list[str] | None, *, seed: bool = False
) -> argparse.Namespace:
    """Parse ``--out``, ``--quick`` (and ``--seed``) and create the output folder.

    Parameters
    ----------
    doc : the example's module docstring; its first line describes the command.
    argv : command-line arguments, or None for ``sys.argv[1:]``.
    seed : also accept ``--seed`` (camera noise seed, default 0), as the closed-loop examples do.

    Returns
    -------
    argparse.Namespace
        The parsed arguments; ``args.out`` exists.
    """
    parser = example_parser(doc)
    if seed:
        parser.add_argument("--seed", type=int, default=0, help="camera noise seed")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    return args


def planner_options(quick: bool) -> dict[str, int]:
    """Planner options for ``--quick`` (20 collocation nodes) or the default (none)."""
    return {"nodes": 20} if quick else {}


def print_written(*paths: str | os.PathLike[str]) -> None:
    """Print ``wrote PATH`` for each file written (the smoke tests read these lines)."""
    for path in paths:
        print(f"wrote {path}")


def fly_and_compare(
    scenario: Scenario,
    out: Path,
    stem: str,
    *,
    seed: int = 0,
    quick: bool = False,
    reference: Mapping[str, float] | None = None,
    reference_label: str = "paper",
) -> list[SimResult]:
    """Fly a scenario with both planners in closed loop, then print and draw the comparison.

    Prints each run's summary as it finishes, then the comparison table, then one ``wrote``
    line per file: a Rerun recording per planner (``{stem}_{planner}.rrd``), the top-down
    figure (``{stem}_top_down.png``) and the speed profiles (``{stem}_speed.png``).

    Parameters
    ----------
    scenario : the scenario to fly.
    out : output folder (must exist).
    stem : start of every output file name, e.g. ``"02_blind_corner"``.
    seed : camera noise seed, shared by both planners.
    quick : 20 collocation nodes instead of 40.
    reference : planner -> time to goal (s) to quote under the table, e.g. the paper's.
    reference_label : where the reference comes from.

    Returns
    -------
    list of SimResult
        One run per planner, secure first.
    """
    results = fly_planners(
        scenario,
        seed=seed,
        rrd=lambda planner: out / f"{stem}_{planner}.rrd",
        report=lambda result: print(result.summary()),
        **planner_options(quick),
    )
    figures = comparison_figures(
        scenario,
        results,
        top_down=out / f"{stem}_top_down.png",
        speed=out / f"{stem}_speed.png",
    )
    print(comparison_table(results, reference, reference_label))
    print_written(*(r.outputs["rrd"] for r in results), *figures.values())
    return results
