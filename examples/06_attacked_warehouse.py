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

import sys
from pathlib import Path

from secure3d.world import load_scenario

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import MAPS, fly_and_compare, parse_example_args


def main(argv: list[str] | None = None) -> int:
    args = parse_example_args(__doc__, argv, seed=True)
    scenario = load_scenario(MAPS / "warehouse.yaml")
    for attack in scenario.server_map.attacks:
        print(f"server attack: {attack.describe()}")
    fly_and_compare(scenario, args.out, "06_warehouse", seed=args.seed, quick=args.quick)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
