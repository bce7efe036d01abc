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

import argparse
from pathlib import Path

from secure3d.simulation.campaign import (
    PAPER_BLIND_CORNER,
    PAPER_BLIND_CORNER_LABEL,
    comparison_figures,
    comparison_table,
    fly_planners,
)
from secure3d.world import load_scenario

MAPS = Path(__file__).resolve().parents[1] / "maps"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/examples"), help="output folder")
    parser.add_argument("--quick", action="store_true", help="20 collocation nodes instead of 40")
    parser.add_argument("--seed", type=int, default=0, help="camera noise seed")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    scenario = load_scenario(MAPS / "blind_corner.yaml")
    options = {"nodes": 20} if args.quick else {}
    results = fly_planners(
        scenario,
        seed=args.seed,
        rrd=lambda planner: args.out / f"02_blind_corner_{planner}.rrd",
        report=lambda result: print(result.summary()),
        **options,
    )
    figures = comparison_figures(
        scenario,
        results,
        top_down=args.out / "02_blind_corner_top_down.png",
        speed=args.out / "02_blind_corner_speed.png",
    )
    print(comparison_table(results, PAPER_BLIND_CORNER, PAPER_BLIND_CORNER_LABEL))
    for path in (*(r.outputs["rrd"] for r in results), *figures.values()):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
