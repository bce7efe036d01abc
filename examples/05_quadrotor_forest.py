"""05 - A quadrotor through a forest whose map is missing three trunks.

Open clutter instead of a corner: the camera sees far ahead, but trunks hide one another, and the
server deleted (``hide``) or never recorded (``stale``) three trunks near the straight line. The
quadrotor must tilt its thrust to brake, so its reactive sets come from the fitted family of its
braking manoeuvre (DESIGN.md, reactive set). Both planners fly in closed loop; writes Rerun
recordings, a top-down figure (the hidden trunks in black) and the speed profiles.

Run headless::

    .venv/bin/python examples/05_quadrotor_forest.py [--quick] [--out out/examples]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from secure3d.simulation.campaign import comparison_figures, comparison_table, fly_planners
from secure3d.world import load_scenario

MAPS = Path(__file__).resolve().parents[1] / "maps"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/examples"), help="output folder")
    parser.add_argument("--quick", action="store_true", help="20 collocation nodes instead of 40")
    parser.add_argument("--seed", type=int, default=0, help="camera noise seed")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    scenario = load_scenario(MAPS / "forest.yaml")
    print(f"{scenario.name}: hidden trunks {', '.join(scenario.hidden_obstacles)}")
    options = {"nodes": 20} if args.quick else {}
    results = fly_planners(
        scenario,
        seed=args.seed,
        rrd=lambda planner: args.out / f"05_forest_{planner}.rrd",
        report=lambda result: print(result.summary()),
        **options,
    )
    figures = comparison_figures(
        scenario,
        results,
        top_down=args.out / "05_forest_top_down.png",
        speed=args.out / "05_forest_speed.png",
    )
    print(comparison_table(results))
    for path in (*(r.outputs["rrd"] for r in results), *figures.values()):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
