"""04 - The paper's own blind-corner experiment: a differential-drive robot, 2 m sensor range.

A left turn around a known wall, with an obstacle the server deleted just behind it (the paper's
Figs. BasePlanner and Gplanner). The paper's baseline takes 1.67 s and collides; its secure plan
takes 2.50 s and is safe. Both planners fly here in closed loop; the table puts our times next to
the paper's. Writes Rerun recordings, a top-down figure and the speed profiles.

Run headless::

    .venv/bin/python examples/04_planar_blind_corner.py [--quick] [--out out/examples]
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

    scenario = load_scenario(MAPS / "planar_blind_corner.yaml")
    options = {"nodes": 20} if args.quick else {}
    results = fly_planners(
        scenario,
        seed=args.seed,
        rrd=lambda planner: args.out / f"04_planar_blind_corner_{planner}.rrd",
        report=lambda result: print(result.summary()),
        **options,
    )
    figures = comparison_figures(
        scenario,
        results,
        top_down=args.out / "04_planar_blind_corner_top_down.png",
        speed=args.out / "04_planar_blind_corner_speed.png",
    )
    print(comparison_table(results, PAPER_BLIND_CORNER, PAPER_BLIND_CORNER_LABEL))
    for path in (*(r.outputs["rrd"] for r in results), *figures.values()):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
