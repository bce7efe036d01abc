"""The ``secure3d`` command line (also ``python -m secure3d``).

Each subcommand is two small functions, one adding its arguments to an ``argparse`` parser and one
running it, registered in :data:`COMMANDS`. A runner imports what it needs inside its body, so
``secure3d show`` never pays for CasADi or Open3D. Adding a subcommand::

    def _plan_arguments(parser): parser.add_argument("scenario", type=Path)
    def _plan(args): from secure3d.planning.solve import plan; ...; return 0
    COMMANDS = (..., Command("plan", "solve a scenario's planning problem", _plan_arguments, _plan))

Errors that secure3d raises on purpose (:class:`~secure3d.errors.Secure3DError`) and usage errors
print exactly one line ``secure3d: error: <message>`` on stderr and exit with status 2; no
traceback. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

from secure3d import __version__
from secure3d.errors import Secure3DError

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
    parser.add_argument("scenario", type=Path, help="scenario YAML file (see maps/README.md)")
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


COMMANDS: tuple[Command, ...] = (
    Command("show", "validate a scenario file and print its summary", _show_arguments, _show),
)


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line, like every other CLI error."""

    def error(self, message: str) -> NoReturn:
        _fail(f"{message} (see '{self.prog} --help')")
        raise SystemExit(EXIT_USAGE)


def _fail(message: str) -> None:
    print(f"{PROG}: error: {' '.join(message.split())}", file=sys.stderr)


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with one subparser per entry of :data:`COMMANDS`."""
    parser = _Parser(
        prog=PROG,
        description="Secure minimum-time planning for aerial robots whose map cannot be trusted.",
    )
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS:
        p = sub.add_parser(command.name, help=command.help, description=command.help)
        command.add_arguments(p)
        p.set_defaults(run=command.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status (0 success, 2 bad input).

    Parameters
    ----------
    argv : sequence of str, optional
        Arguments without the program name; default ``sys.argv[1:]``.
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version and usage errors
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    try:
        return args.run(args)
    except Secure3DError as exc:
        _fail(str(exc))
        return EXIT_USAGE
    except KeyboardInterrupt:
        _fail("interrupted")
        return 130
