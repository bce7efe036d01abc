"""The ``secure3d`` command line (also ``python -m secure3d``).

Each subcommand is two small functions, one adding its arguments to an ``argparse`` parser and one
running it, registered in :data:`COMMANDS`. A runner imports what it needs inside its body, so
``secure3d show`` never pays for CasADi or Open3D. Adding a subcommand::

    def _certify_arguments(parser): parser.add_argument("scenario", type=Path)
    def _certify(args): from secure3d.planning import certify; ...; return 0
    COMMANDS = (..., Command("certify", "certify a plan", _certify_arguments, _certify))

Subcommands: ``show``, ``plan``, ``simulate``, ``campaign`` and ``campaign-merge``
(:mod:`secure3d.cli_campaign`), ``bench``, ``reactive fit``, ``demo`` (:mod:`secure3d.cli_demo`),
``map`` (:mod:`secure3d.cli_map`) and ``paper`` (:mod:`secure3d.cli_paper`); what they share is in
:mod:`secure3d.cli_common`. Every output file
is written atomically (temporary file + rename), into folders created on demand.

Errors that secure3d raises on purpose (:class:`~secure3d.errors.Secure3DError`) and usage errors
print exactly one line ``secure3d: error: <message>`` on stderr and exit with status 2; no
traceback. Anything else is a bug and keeps its traceback. ``plan`` exits with 1 when a planner
did not return a successful (for the secure planner: certified) plan; Ctrl-C exits with 130.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from secure3d import __version__
from secure3d.cli_campaign import _campaign, _campaign_arguments, _merge, _merge_arguments
from secure3d.cli_common import (  # noqa: F401  (_bundled_scenario: part of the CLI's surface)
    _BENCHMARKS,
    _REPO,
    _SCENARIO_HELP,
    PLANNER_CHOICES,
    _add_planner_options,
    _add_replan_defer,
    _bundled_scenario,
    _check_seed,
    _output_dir,
    _output_path,
    _planner_options,
    _planners,
    _print_run,
)
from secure3d.cli_demo import _demo, _demo_arguments
from secure3d.cli_map import map_arguments, run_map
from secure3d.cli_paper import paper_arguments, run_paper_command
from secure3d.errors import ConfigError, Secure3DError
from secure3d.outputs import check_output_path
from secure3d.sigint import EXIT_INTERRUPTED, cli_interrupts
from secure3d.sigint import requested as interrupt_requested

if TYPE_CHECKING:  # pragma: no cover
    pass

PROG = "secure3d"
#: Exit status for bad input (argparse's convention).
EXIT_USAGE = 2


@dataclass(frozen=True)
class Command:
    """One subcommand: its name, one-line help, argument declaration and runner."""

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


def _show_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", type=Path, help=_SCENARIO_HELP + "; format: maps/README.md")
    parser.add_argument(
        "--json", action="store_true", help="print the full scenario as JSON instead"
    )


def _show(args: argparse.Namespace) -> int:
    from secure3d.world.scenario import load_scenario, scenario_to_dict

    scenario = load_scenario(args.scenario)
    if args.json:
        print(json.dumps(scenario_to_dict(scenario), indent=2))
    else:
        print(scenario.summary())
    return 0


#: Columns of the ``plan`` table.
PLAN_COLUMNS = (
    "planner",
    "status",
    "final time",
    "build",
    "solve",
    "iterations",
    "certified",
    "margin",
)


# ---- plan --------------------------------------------------------------------------------------


def _plan_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", type=Path, help=_SCENARIO_HELP)
    parser.add_argument(
        "--planner", choices=PLANNER_CHOICES, default="both", help="planner(s) to run (both)"
    )
    _add_planner_options(parser)
    parser.add_argument(
        "--png", type=Path, metavar="FILE", help="write a top-down figure of the plans"
    )
    parser.add_argument("--json", action="store_true", help="print the results as JSON")


def _plan_json(result: object) -> dict[str, object]:
    cert = result.certificate
    return {
        "planner": result.planner,
        "status": result.status.value,
        "ok": result.ok,
        "message": result.message,
        "final_time": result.final_time if len(result.times) else None,
        "build_time": result.build_time,
        "solve_time": result.solve_time,
        "iterations": result.iterations,
        "solver": result.solver,
        "lookback_rule": result.lookback_rule,
        "certified": None if cert is None else cert.ok,
        "min_margin": None if cert is None else cert.min_margin,
        "times": result.times.tolist(),
        "positions": result.positions.tolist(),
        "speeds": result.speeds.tolist(),
    }


def _plan(args: argparse.Namespace) -> int:
    """Exit 0 when every planner returned a successful (and, if secure, certified) plan, else 1."""
    from secure3d.planning import NLPCache, plan
    from secure3d.simulation.campaign import format_table
    from secure3d.world.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    options = _planner_options(args)
    png = _output_path(args.png)
    cache = NLPCache()
    results = [plan(scenario, p, cache=cache, **options) for p in _planners(args.planner)]
    if args.json:
        print(json.dumps([_plan_json(r) for r in results], indent=2))
    else:
        rows = []
        for r in results:
            cert = r.certificate
            rows.append(
                (
                    r.planner,
                    r.status.value,
                    f"{r.final_time:.2f} s" if len(r.times) else "-",
                    f"{1e3 * r.build_time:.0f} ms",
                    f"{1e3 * r.solve_time:.0f} ms",
                    str(r.iterations),
                    "-" if cert is None else ("yes" if cert.ok else "NO"),
                    "-" if cert is None else f"{cert.min_margin:+.3f} m",
                )
            )
        rule = options.get("lookback", scenario.planner.lookback)
        print(f"{scenario.name}: {len(results)} plan(s) in the server's map, look-back rule {rule}")
        print(format_table(PLAN_COLUMNS, rows))
        for r in results:
            if not r.ok:
                print(f"{r.planner}: {' '.join(r.message.split())}")
    if png is not None:
        from secure3d.viz.run_figures import plans_figure

        plans_figure(scenario, results, png)
        print(f"wrote {png}", file=sys.stderr if args.json else sys.stdout)
    return 0 if all(r.ok for r in results) else 1


# ---- simulate ----------------------------------------------------------------------------------


def _simulate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", type=Path, help=_SCENARIO_HELP)
    parser.add_argument(
        "--planner",
        choices=PLANNER_CHOICES,
        help="planner(s) to fly (both; a campaign's failure file: its run's planner)",
    )
    parser.add_argument(
        "--seed",
        type=int,
        metavar="N",
        help="camera noise seed (0; a campaign's failure file: its run's seed)",
    )
    _add_planner_options(parser)
    parser.add_argument(
        "--rrd",
        type=Path,
        metavar="FILE",
        help="write a Rerun recording (with both planners: FILE_secure.rrd and FILE_baseline.rrd)",
    )
    parser.add_argument(
        "--png", type=Path, metavar="FILE", help="write a top-down figure of the flights"
    )
    parser.add_argument(
        "--speed-png", type=Path, metavar="FILE", help="write the speed profiles of the flights"
    )
    parser.add_argument(
        "--replan-latency",
        type=float,
        default=0.0,
        metavar="S",
        help="simulated seconds a replan in flight takes; the robot follows its old plan meanwhile (0)",
    )
    _add_replan_defer(parser, with_latency=True)
    parser.add_argument("--events", action="store_true", help="print every event of each run")
    parser.add_argument(
        "--json",
        action="store_true",
        help="print the runs as JSON on stdout (SimResult.to_dict) instead of the text report",
    )


def _per_planner(path: Path | None, planner: str, several: bool) -> Path | None:
    if path is None or not several:
        return path
    return path.with_name(f"{path.stem}_{planner}{path.suffix or '.rrd'}")


def _failure_defaults(args: argparse.Namespace) -> None:
    """Planner, seed and replan deferral of a campaign's failure file, unless given."""
    from secure3d.simulation.campaign_store import failure_defaults

    found = failure_defaults(args.scenario)
    if args.planner is None:
        args.planner = found.get("planner", "both")
    if args.seed is None:
        args.seed = int(found.get("seed", 0))
    if args.replan_defer is None and "replan_defer" in found and not args.replan_latency:
        args.replan_defer = float(found["replan_defer"])


def _simulate(args: argparse.Namespace) -> int:
    from secure3d.session import fly_planners
    from secure3d.simulation.compare import comparison_table
    from secure3d.viz.run_figures import comparison_figures
    from secure3d.world.scenario import load_scenario

    scenario = load_scenario(args.scenario)
    _failure_defaults(args)
    _check_seed(args.seed)
    planners = _planners(args.planner)
    rrd, png, speed = (
        None if p is None else check_output_path(p, (suffix,), flag)
        for p, suffix, flag in (
            (args.rrd, ".rrd", "--rrd"),
            (args.png, ".png", "--png"),
            (args.speed_png, ".png", "--speed-png"),
        )
    )
    several = len(planners) > 1
    results = fly_planners(
        scenario,
        planners,
        args.seed,
        rrd=lambda planner: _per_planner(rrd, planner, several),
        report=(lambda result: None) if args.json else (lambda r: _print_run(r, args.events)),
        replan_latency=args.replan_latency,
        replan_defer=args.replan_defer,
        **_planner_options(args),
    )
    figures = comparison_figures(scenario, results, top_down=png, speed=speed)
    if args.json:
        print(json.dumps([r.to_dict() for r in results], indent=1))
        return 0
    if several:
        print()
        print(comparison_table(results))
    for path in figures.values():
        print(f"wrote {path}")
    return 0


# ---- bench -------------------------------------------------------------------------------------


def _bench_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "target",
        choices=("mapping", "planner", "closed_loop", "campaign"),
        help="mapping: benchmarks/bench_mapping.py; planner: benchmarks/bench_planner.py;"
        " closed_loop: benchmarks/bench_closed_loop.py (set-up, flight and real-time factors);"
        " campaign: a 20-variant campaign on maps/blind_corner.yaml (out/bench_campaign/<time>)",
    )
    parser.add_argument(
        "args", nargs=argparse.REMAINDER, help="passed on (campaign: options of 'campaign')"
    )


def _run_script(name: str, argv: Sequence[str], scripts: Path) -> int:
    """Run the repository script ``scripts / name`` in a fresh interpreter; its exit status is
    ours."""
    import subprocess

    script = scripts / name
    if not script.is_file():
        raise ConfigError(
            f"{script} not found: the benchmarks ship with the source repository, not the package"
        )
    return subprocess.run([sys.executable, str(script), *argv], check=False).returncode


def _bench(args: argparse.Namespace) -> int:
    import time

    if args.target == "campaign":
        scenario = _bundled_scenario("blind_corner")
        # A fresh folder per benchmark: a campaign never overwrites another's runs.csv.
        stamp = time.strftime("%Y%m%d-%H%M%S")
        defaults = ["-n", "20", "--out", f"out/bench_campaign/{stamp}"]
        return main(["campaign", str(scenario), *defaults, *args.args])
    return _run_script(f"bench_{args.target}.py", args.args, args.scripts)


# ---- reactive ----------------------------------------------------------------------------------


def _reactive_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "action",
        choices=("fit",),
        help="fit: fit the shipped reactive-set families (benchmarks/fit_reactive_sets.py;"
        " 'secure3d reactive fit --help' lists its options)",
    )
    parser.add_argument("args", nargs=argparse.REMAINDER, help="passed on to the fitting script")


def _reactive(args: argparse.Namespace) -> int:
    return _run_script("fit_reactive_sets.py", args.args, args.scripts)


COMMANDS: tuple[Command, ...] = (
    Command("show", "validate a scenario file and print its summary", _show_arguments, _show),
    Command(
        "plan", "plan a scenario with the secure and/or baseline planner", _plan_arguments, _plan
    ),
    Command(
        "simulate",
        "fly a scenario in closed loop (the paper's Algorithm 1)",
        _simulate_arguments,
        _simulate,
    ),
    Command(
        "campaign",
        "fly randomised hidden-obstacle variants with each planner",
        _campaign_arguments,
        _campaign,
    ),
    Command(
        "campaign-merge",
        "combine campaign folders (shards) and recompute the statistics",
        _merge_arguments,
        _merge,
    ),
    Command(
        "bench",
        "run a benchmark (mapping, planner, closed_loop or campaign)",
        _bench_arguments,
        _bench,
    ),
    Command(
        "reactive",
        "reactive-set tools ('fit' refits the shipped families)",
        _reactive_arguments,
        _reactive,
    ),
    Command(
        "demo",
        "fly the blind corner with both planners: recordings, figures, table",
        _demo_arguments,
        _demo,
    ),
    Command("map", "map files: 'info FILE', 'convert IN OUT'", map_arguments, run_map),
    Command(
        "paper",
        "regenerate the paper's experiments: figures, recordings, table against the paper",
        paper_arguments,
        run_paper_command,
    ),
)


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line, like every other CLI error."""

    def error(self, message: str) -> NoReturn:
        _fail(f"{message} (see '{self.prog} --help')")
        raise SystemExit(EXIT_USAGE)


class _Version(argparse.Action):
    """``--version``: this package's version, and the numpy kernels the process runs
    (:func:`secure3d.numpy_kernels`), which decide a plan's last bits; asked only when used."""

    def __init__(self, option_strings: list[str], dest: str, **kwargs: object) -> None:
        super().__init__(option_strings, dest, nargs=0, help="show the version and exit")

    def __call__(self, parser: argparse.ArgumentParser, *args: object) -> NoReturn:
        from secure3d import numpy_kernels

        k = numpy_kernels()
        kernels = (
            f"numpy {k['numpy']}, kernels {k['mode']} ({' '.join(k['dispatch']) or 'baseline'})"
        )
        print(f"{PROG} {__version__}\n{kernels}: {k['reason']}")
        parser.exit(0)


def _fail(message: str) -> None:
    print(f"{PROG}: error: {' '.join(message.split())}", file=sys.stderr)


def _log_to_stderr() -> None:
    """The library's INFO lines (a long flight's heartbeat, an on-demand reactive-set fit) on
    stderr, once per process."""
    logger = logging.getLogger("secure3d")
    if not any(getattr(h, "_secure3d_cli", False) for h in logger.handlers):
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter(f"{PROG}: %(message)s"))
        handler._secure3d_cli = True  # type: ignore[attr-defined]
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)


def build_parser(scripts: Path = _BENCHMARKS) -> argparse.ArgumentParser:
    """The top-level parser with one subparser per entry of :data:`COMMANDS`; ``bench`` and
    ``reactive fit`` run the scripts in the folder ``scripts`` (offered only if it exists)."""
    parser = _Parser(
        prog=PROG,
        description="Secure minimum-time planning for aerial robots whose map cannot be trusted.",
    )
    parser.add_argument("--version", action=_Version)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        if command.name == "bench" and not scripts.is_dir():
            continue  # an installed wheel has no benchmark scripts
        p = sub.add_parser(command.name, help=command.help, description=command.help)
        command.add_arguments(p)
        p.set_defaults(run=command.run, scripts=scripts)
    return parser


def main(argv: Sequence[str] | None = None, *, scripts: Path = _BENCHMARKS) -> int:
    """Run the command line; return the exit status (0 success, 1 I/O error, 2 bad input,
    130 interrupted by Ctrl-C, within a second whatever runs: :mod:`secure3d.sigint`).

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.
    scripts : folder of the repository scripts that ``bench`` and ``reactive fit`` run (default:
        the source checkout's ``benchmarks/``).
    """
    with cli_interrupts(f"{PROG}: error: interrupted"):
        try:
            return _run(argv, scripts)
        except KeyboardInterrupt:
            return _interrupted()
        except Exception as exc:
            if interrupt_requested():  # a Ctrl-C that surfaced as another exception
                return _interrupted()
            return _report(exc)


def _interrupted() -> int:
    _fail("interrupted")
    return EXIT_INTERRUPTED


def _report(exc: Exception) -> int:
    """The one-line report and exit status of an expected error; anything else propagates."""
    if isinstance(exc, Secure3DError):
        _fail(str(exc))
        return EXIT_USAGE
    if isinstance(exc, BrokenPipeError):
        # the reader went away (`secure3d show ... | head`): no traceback; later writes to the
        # closed stdout must not raise again at interpreter exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        _fail("output closed before it was all written (broken pipe)")
        return 1
    if isinstance(exc, OSError):
        where = f"{exc.filename}: " if exc.filename else ""
        _fail(f"{where}{exc.strerror or exc}")
        return 1
    raise exc


def _run(argv: Sequence[str] | None, scripts: Path) -> int:
    parser = build_parser(scripts)
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    _log_to_stderr()
    status = args.run(args)
    sys.stdout.flush()  # a closed pipe shows here, not as a traceback at interpreter exit
    return status
