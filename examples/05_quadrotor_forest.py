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

import sys
from pathlib import Path

from secure3d.world import load_scenario

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import MAPS, fly_and_compare, parse_example_args


def main(argv: list[str] | None = None) -> int:
    args = parse_example_args(__doc__, argv, seed=True)
    scenario = load_scenario(MAPS / "forest.yaml")
    print(f"{scenario.name}: hidden trunks {', '.join(scenario.hidden_obstacles)}")
    fly_and_compare(scenario, args.out, "05_forest", seed=args.seed, quick=args.quick)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
