"""``secure3d paper``: regenerate every experiment of the paper (logic in :mod:`secure3d.paper`).

Progress goes to stderr, one line per step; the comparison table (``paper.md``) to stdout at the
end, then one ``wrote PATH`` line per file. Ctrl-C stops it like every other command
(:mod:`secure3d.sigint`); files already written stay, the one being written is removed.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def paper_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--out`` and ``--quick`` to the ``paper`` command's parser."""
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("out/paper"),
        metavar="DIR",
        help="output folder (out/paper)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="20 collocation nodes instead of 40: faster, coarser plans (a smoke test)",
    )


def run_paper_command(args: argparse.Namespace) -> int:
    """Run ``secure3d paper``."""
    from secure3d.outputs import check_output_path
    from secure3d.paper import run_paper

    check_output_path(args.out / "paper.md", (".md",), "--out")
    start = time.perf_counter()

    def progress(line: str) -> None:
        print(f"secure3d paper [{time.perf_counter() - start:5.1f} s] {line}", file=sys.stderr)

    run = run_paper(args.out, quick=args.quick, progress=progress)
    print(run.markdown(args.quick).rstrip())
    print()
    for path in run.files:
        print(f"wrote {path}")
    return 0
