"""06 - A warehouse whose map server lies: a phantom pallet and a shifted shelf.

Deleting obstacles is not the only attack. Here the server invents a pallet that closes one aisle
(a *phantom*: the robot takes a detour it did not need until its camera shows the aisle empty and
sensor evidence overrides the claim) and reports a shelf 0.6 m away from where it stands (a
*shift*: the free space it claims is occupied). The robot's map keeps sensor evidence and server
claims in separate trust layers (DESIGN.md, map update rules). Both planners fly in closed loop;
writes Rerun recordings, a top-down figure (claimed positions dashed) and the speed profiles.

Run headless::

    .venv/bin/python examples/06_attacked_warehouse.py [--quick] [--out out/examples]
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

    scenario = load_scenario(MAPS / "warehouse.yaml")
    for attack in scenario.server_map.attacks:
        print(f"server attack: {attack.describe()}")
    options = {"nodes": 20} if args.quick else {}
    results = fly_planners(
        scenario,
        seed=args.seed,
        rrd=lambda planner: args.out / f"06_warehouse_{planner}.rrd",
        report=lambda result: print(result.summary()),
        **options,
    )
    figures = comparison_figures(
        scenario,
        results,
        top_down=args.out / "06_warehouse_top_down.png",
        speed=args.out / "06_warehouse_speed.png",
    )
    print(comparison_table(results))
    for path in (*(r.outputs["rrd"] for r in results), *figures.values()):
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
