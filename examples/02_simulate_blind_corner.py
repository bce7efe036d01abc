"""02 - Fly the blind corner in closed loop with both planners (the paper's Algorithm 1).

The simulator sees the true world, crate included; the robot only learns about the crate from its
depth camera. The baseline meets the crate at speed (collision, or a last-moment take-over by the
reactive controller); the secure planner has seen everything its emergency stop could need and
replans calmly. Writes one Rerun recording per planner (replay with ``rerun FILE.rrd``), a
top-down figure of both flights and their speed profiles, and prints the comparison table.

Run headless::

    .venv/bin/python examples/02_simulate_blind_corner.py [--quick] [--out out/examples]
"""

from __future__ import annotations

import sys
from pathlib import Path

from secure3d.simulation.campaign import PAPER_BLIND_CORNER, PAPER_BLIND_CORNER_LABEL
from secure3d.world import load_scenario

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import MAPS, fly_and_compare, parse_example_args


def main(argv: list[str] | None = None) -> int:
    args = parse_example_args(__doc__, argv, seed=True)
    scenario = load_scenario(MAPS / "blind_corner.yaml")
    fly_and_compare(
        scenario,
        args.out,
        "02_blind_corner",
        seed=args.seed,
        quick=args.quick,
        reference=PAPER_BLIND_CORNER,
        reference_label=PAPER_BLIND_CORNER_LABEL,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
