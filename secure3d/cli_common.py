"""What the ``secure3d`` subcommands share: planner options, output folders, shipped scenario
names, seeds and the one-line run summary (:mod:`secure3d.cli` and its command modules)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from secure3d.errors import ConfigError

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.simulation.closed_loop import SimResult

PLANNER_CHOICES = ("secure", "baseline", "both")


#: The repository's benchmarks/ folder: ``bench`` is offered only in a source checkout (the
#: scripts are not part of the installed package).
_REPO = Path(__file__).resolve().parents[1]


_SCENARIO_HELP = "scenario YAML file or a shipped scenario's name (blind_corner, forest, ...)"


_BENCHMARKS = _REPO / "benchmarks"


def _planners(choice: str) -> tuple[str, ...]:
    return ("secure", "baseline") if choice == "both" else (choice,)


def _add_planner_options(parser: argparse.ArgumentParser) -> None:
    """Planner settings shared by plan, simulate and campaign (default: the scenario's)."""
    group = parser.add_argument_group("planner options (default: the scenario's planner section)")
    group.add_argument("--nodes", type=int, metavar="K", help="collocation nodes K")
    group.add_argument("--solver", choices=("ipopt", "fatrop"), help="NLP solver")
    group.add_argument(
        "--lookback", choices=("adaptive", "fixed"), help="look-back rule of eq. NLP's visibility"
    )
    group.add_argument(
        "--plan-budget",
        type=float,
        metavar="S",
        help="wall-clock budget of one plan call, retries included (s; default 60)",
    )
    group.add_argument(
        "--slot-pick",
        choices=("nearest", "directions"),
        help="obstacle slots of a node: its nearest boxes (default), or first the nearest in each"
        " direction (secure planner, opt-in)",
    )


def _planner_options(args: argparse.Namespace) -> dict[str, object]:
    names = ("nodes", "solver", "lookback", "plan_budget", "slot_pick")
    return {name: getattr(args, name) for name in names if getattr(args, name) is not None}


def _output_path(path: Path | None) -> Path | None:
    """``path`` with its folder created (outputs themselves are written atomically)."""
    if path is not None:
        _output_dir(path.parent)
    return path


def _output_dir(folder: Path) -> Path:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ConfigError(f"output folder {str(folder)!r}: {exc.strerror or exc}") from None
    return folder


def _bundled_scenario(name: str) -> Path:
    """The shipped scenario ``name`` (``secure3d/maps/NAME.yaml``)."""
    from secure3d.world.bundled import resolve_scenario

    return resolve_scenario(name)


def _add_replan_defer(parser: argparse.ArgumentParser, with_latency: bool = False) -> None:
    default = "default 0.5, or 0 with --replan-latency" if with_latency else "default 0.5"
    parser.add_argument(
        "--replan-defer",
        type=float,
        default=None,
        metavar="S",
        help="when new evidence breaks the plan but its first failing manoeuvre is more than S"
        f" seconds ahead, keep following it and replan S seconds before ({default}; 0: replan"
        " at once)",
    )


def _check_seed(seed: int) -> None:
    if seed < 0:
        raise ConfigError(f"--seed: must be a non-negative integer (got {seed})")


def _print_run(result: SimResult, events: bool = False) -> None:
    print(result.summary())
    if events:
        print("\n".join(f"  {e}" for e in result.events))
    for path in result.outputs.values():
        print(f"  wrote {path}")
