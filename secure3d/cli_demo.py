"""``secure3d demo``: the blind corner flown by both planners, with figures and recordings."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from secure3d.cli_common import _bundled_scenario, _check_seed, _output_dir, _print_run


def _demo_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out", type=Path, default=Path("out"), metavar="DIR", help="output folder (out)"
    )
    parser.add_argument(
        "--quick", action="store_true", help="fewer collocation nodes (20): faster, coarser plans"
    )
    parser.add_argument(
        "--scenario",
        type=Path,
        metavar="FILE",
        help="fly this scenario instead of the blind corner",
    )
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="camera noise seed (0)")


def _rerun_command() -> str:
    """The Rerun viewer installed beside this Python (``.venv/bin/rerun``), which need not be on
    PATH; plain ``rerun`` when it is not there."""
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.is_file() else "rerun"


def _demo(args: argparse.Namespace) -> int:
    from secure3d.session import fly_planners
    from secure3d.simulation.campaign import (
        PAPER_BLIND_CORNER,
        PAPER_BLIND_CORNER_LABEL,
        comparison_table,
    )
    from secure3d.viz.run_figures import comparison_figures
    from secure3d.world.scenario import load_scenario

    scenario = load_scenario(args.scenario or _bundled_scenario("blind_corner"))
    out = _output_dir(args.out)
    options = {"nodes": 20} if args.quick else {}
    name = scenario.name
    _check_seed(args.seed)
    quick = " (quick: 20 nodes)" if args.quick else ""
    print(f"Flying {name!r} with the secure planner and the baseline{quick}.")
    results = fly_planners(
        scenario,
        ("secure", "baseline"),
        args.seed,
        rrd=lambda planner: out / f"{name}_{planner}.rrd",
        report=_print_run,
        **options,
    )
    figures = comparison_figures(
        scenario, results, top_down=out / f"{name}_top_down.png", speed=out / f"{name}_speed.png"
    )
    for path in figures.values():
        print(f"  wrote {path}")
    print()
    if name == "blind_corner":
        print(comparison_table(results, PAPER_BLIND_CORNER, PAPER_BLIND_CORNER_LABEL))
    else:
        print(comparison_table(results))
    print(f"\nReplay a flight with: {_rerun_command()} {out / f'{name}_secure.rrd'}")
    return 0
