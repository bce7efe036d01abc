"""The ``secure3d`` command line (also ``python -m secure3d``).

Each subcommand is two small functions, one adding its arguments to an ``argparse`` parser and one
running it, registered in :data:`COMMANDS`. A runner imports what it needs inside its body, so
``secure3d show`` never pays for CasADi or Open3D. Adding a subcommand::

    def _certify_arguments(parser): parser.add_argument("scenario", type=Path)
    def _certify(args): from secure3d.planning import certify; ...; return 0
    COMMANDS = (..., Command("certify", "certify a plan", _certify_arguments, _certify))

Subcommands: ``show``, ``plan``, ``simulate``, ``campaign`` (logic in
:mod:`secure3d.simulation.campaign` and :mod:`secure3d.simulation.campaign_run`),
``campaign-merge`` (:mod:`secure3d.simulation.campaign_store`), ``bench``, ``reactive fit``,
``demo``, ``map`` (:mod:`secure3d.cli_map`) and ``paper`` (:mod:`secure3d.cli_paper`). Every output file
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
from secure3d.cli_map import map_arguments, run_map
from secure3d.cli_paper import paper_arguments, run_paper_command
from secure3d.errors import ConfigError, Secure3DError
from secure3d.outputs import check_output_path
from secure3d.sigint import EXIT_INTERRUPTED, cli_interrupts
from secure3d.sigint import requested as interrupt_requested

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.simulation.closed_loop import SimResult

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


PLANNER_CHOICES = ("secure", "baseline", "both")
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
#: The repository's benchmarks/ folder: ``bench`` is offered only in a source checkout (the
#: scripts are not part of the installed package).
_REPO = Path(__file__).resolve().parents[1]
_SCENARIO_HELP = "scenario YAML file or a shipped scenario's name (blind_corner, forest, ...)"
_BENCHMARKS = _REPO / "benchmarks"


def _planners(choice: str) -> tuple[str, ...]:
    return ("secure", "baseline") if choice == "both" else (choice,)


def _add_planner_options(parser: argparse.ArgumentParser) -> None:
    """Planner settings shared by plan, simulate, campaign and demo (default: the scenario's)."""
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


def _planner_options(args: argparse.Namespace) -> dict[str, object]:
    names = ("nodes", "solver", "lookback", "plan_budget")
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
        from secure3d.viz.figures import top_down_figure
        from secure3d.world.attacks import server_claim

        claim = server_claim(scenario)
        top_down_figure(
            scenario.world.bounds,
            scenario.world.boxes,
            out_path=png,
            true_meshes=scenario.world.meshes,
            claimed_boxes=claim.boxes,
            claimed_meshes=claim.meshes,
            hidden_names=scenario.hidden_obstacles,
            plans=[r for r in results if len(r.positions)],
            start=scenario.start.position,
            goal=scenario.goal.position,
            title=f"{scenario.name}: plans in the server's map",
        )
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


def _per_planner(path: Path | None, planner: str, several: bool) -> Path | None:
    if path is None or not several:
        return path
    return path.with_name(f"{path.stem}_{planner}{path.suffix or '.rrd'}")


def _print_run(result: SimResult, events: bool = False) -> None:
    print(result.summary())
    if events:
        print("\n".join(f"  {e}" for e in result.events))
    for path in result.outputs.values():
        print(f"  wrote {path}")


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
    from secure3d.simulation.campaign import comparison_figures, comparison_table, fly_planners
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


# ---- campaign ----------------------------------------------------------------------------------


def _planner_names(text: str) -> tuple[str, ...]:
    names = tuple(p.strip() for p in text.split(",") if p.strip())
    bad = [p for p in names if p not in ("secure", "baseline")]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"expected a comma-separated list of secure, baseline (got {text!r})"
        )
    return names


def _campaign_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", type=Path, help="base " + _SCENARIO_HELP)
    parser.add_argument("-n", type=int, required=True, help="number of hidden-obstacle variants")
    parser.add_argument(
        "--planners",
        type=_planner_names,
        default=("secure", "baseline"),
        metavar="LIST",
        help="comma-separated planners to fly (secure,baseline)",
    )
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="seed of the variants (0)")
    parser.add_argument(
        "--workers", type=int, metavar="W", help="worker processes (default: the number of CPUs)"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("out/campaign"),
        metavar="DIR",
        help="output folder (out/campaign)",
    )
    from secure3d.world.family_registry import FAMILIES

    parser.add_argument(
        "--kind",
        choices=("auto", "corner", "forest", *FAMILIES),
        default="auto",
        help="where hidden obstacles go (auto), or a scenario family: "
        + "; ".join(f"{f.name}: {f.description}" for f in FAMILIES.values()),
    )
    parser.add_argument(
        "--count", type=int, default=1, metavar="C", help="hidden obstacles per variant (1)"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_replan_defer(parser)
    _add_planner_options(parser)
    group = parser.add_argument_group("scale and faults")
    group.add_argument(
        "--backend",
        choices=("process", "ray"),
        default="process",
        help="process: worker processes here; ray: Ray actors (pip install 'secure3d[ray]')",
    )
    group.add_argument(
        "--address",
        metavar="ADDR",
        help="with --backend ray: join this Ray cluster (auto, ray://host:10001) instead of a"
        " local Ray",
    )
    group.add_argument(
        "--resume",
        action="store_true",
        help="continue the campaign in --out: fly only the runs missing from its runs.csv",
    )
    group.add_argument(
        "--shard",
        metavar="K/N",
        help="fly only variants i with i %% N == K-1 (combine shards with campaign-merge)",
    )
    group.add_argument(
        "--run-timeout",
        type=float,
        metavar="S",
        help="stop a run after S wall seconds (set-up included): an error row",
    )
    group.add_argument(
        "--retries",
        type=int,
        default=1,
        metavar="R",
        help="fly a run again up to R times when its worker dies (1)",
    )


def _campaign(args: argparse.Namespace) -> int:
    from secure3d.simulation.campaign import run_campaign

    result = run_campaign(
        args.scenario,
        args.n,
        planners=args.planners,
        seed=args.seed,
        workers=args.workers,
        out_dir=_output_dir(args.out),
        progress=not args.no_progress,
        kind=args.kind,
        count=args.count,
        replan_defer=args.replan_defer,
        backend=args.backend,
        address=args.address,
        resume=args.resume,
        shard=args.shard,
        run_timeout=args.run_timeout,
        retries=args.retries,
        **_planner_options(args),
    )
    print(result.summary_markdown().rstrip())
    print(f"\nwrote {result.csv_path} and {result.summary_path} (every run: runs.csv)")
    return 0


def _merge_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folders", type=Path, nargs="+", metavar="OUT", help="campaign folders")
    parser.add_argument(
        "--out", type=Path, required=True, metavar="DIR", help="folder for the merged campaign"
    )


def _merge(args: argparse.Namespace) -> int:
    from secure3d.simulation.campaign_store import merge_campaigns

    result = merge_campaigns(args.folders, args.out)
    print(result.summary_markdown().rstrip())
    print(f"\nwrote {result.csv_path} and {result.summary_path} (every run: runs.csv)")
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


def _run_script(name: str, argv: Sequence[str]) -> int:
    """Run a repository script in a fresh interpreter; its exit status is ours."""
    import subprocess

    script = _BENCHMARKS / name
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
    return _run_script(f"bench_{args.target}.py", args.args)


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
    return _run_script("fit_reactive_sets.py", args.args)


# ---- demo --------------------------------------------------------------------------------------


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
    from secure3d.simulation.campaign import (
        PAPER_BLIND_CORNER,
        PAPER_BLIND_CORNER_LABEL,
        comparison_figures,
        comparison_table,
        fly_planners,
    )
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


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per entry of :data:`COMMANDS`."""
    parser = _Parser(
        prog=PROG,
        description="Secure minimum-time planning for aerial robots whose map cannot be trusted.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        if command.name == "bench" and not _BENCHMARKS.is_dir():
            continue  # an installed wheel has no benchmark scripts
        p = sub.add_parser(command.name, help=command.help, description=command.help)
        command.add_arguments(p)
        p.set_defaults(run=command.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status (0 success, 1 I/O error, 2 bad input,
    130 interrupted by Ctrl-C, within a second whatever runs: :mod:`secure3d.sigint`).

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.
    """
    with cli_interrupts(f"{PROG}: error: interrupted"):
        try:
            return _run(argv)
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


def _run(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    _log_to_stderr()
    status = args.run(args)
    sys.stdout.flush()  # a closed pipe shows here, not as a traceback at interpreter exit
    return status
