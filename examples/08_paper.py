"""08 - Every experiment of the paper in one call: what ``secure3d paper`` runs.

The 1D example's reactive sets, the 50 cm and 20 cm passages (Fig. ThreadNeedle: 1.60 s and
2.12 s), and the blind corner with both planners in open and closed loop (Figs. BasePlanner and
Gplanner: the baseline plans 1.67 s and collides, the secure planner plans 2.50 s and stops
safely). The scenarios are ``maps/paper_*.yaml``; each states which of its values the paper gives
and which are inferred. Writes one figure per plan or flight, a Rerun recording per passage and
per flight, and ``paper.md``, the table of the paper's figures against ours, which it also prints.

Run headless::

    .venv/bin/python examples/08_paper.py [--quick] [--out out/examples]
"""

from __future__ import annotations

import sys
from pathlib import Path

from secure3d.paper import run_paper

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import parse_example_args, print_written


def main(argv: list[str] | None = None) -> int:
    args = parse_example_args(__doc__, argv)
    run = run_paper(args.out / "08_paper", quick=args.quick, progress=print)
    print(run.markdown(args.quick))
    print_written(*run.files)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
