"""04 - A blind corner in a larger room: a differential-drive robot, 2 m sensor range.

``maps/planar_blind_corner.yaml``: the paper's experiment scaled up (4 m and 3 m legs, a 0.2 m body,
2 m/s^2), flown with the closed loop's defaults; ``08_paper.py`` runs the paper's own set-up. A left
turn around a known wall, with an obstacle the server deleted just behind it (the paper's
Figs. BasePlanner and Gplanner). The paper's baseline takes 1.67 s and collides; its secure plan
takes 2.50 s and is safe. Both planners fly here in closed loop; the table puts our times next to
the paper's. Writes Rerun recordings, a top-down figure and the speed profiles.

Run headless::

    .venv/bin/python examples/04_planar_blind_corner.py [--quick] [--out out/examples]
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
    scenario = load_scenario(MAPS / "planar_blind_corner.yaml")
    fly_and_compare(
        scenario,
        args.out,
        "04_planar_blind_corner",
        seed=args.seed,
        quick=args.quick,
        reference=PAPER_BLIND_CORNER,
        reference_label=PAPER_BLIND_CORNER_LABEL,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
