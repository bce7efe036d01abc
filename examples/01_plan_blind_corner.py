"""01 - Plan the blind corner with the secure planner and the baseline (no flight yet).

Both planners solve the paper's minimum-time NLP in the *server's* map, where the crate just
around the corner has been deleted. The baseline cuts the inside of the corner at full speed; the
secure planner keeps every reactive set S_r(x(t)) inside an earlier camera frustum (eq. NLP), so
it swings wide and slows before the corner. The secure plan is then checked by the independent
certificate. Writes a top-down figure of both plans with their reactive sets.

Run headless::

    .venv/bin/python examples/01_plan_blind_corner.py [--quick] [--out out/examples]
"""

from __future__ import annotations

import sys
from pathlib import Path

from secure3d.planning import NLPCache, plan
from secure3d.viz.figures import top_down_figure
from secure3d.world import load_scenario, server_claim

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import MAPS, parse_example_args, planner_options


def main(argv: list[str] | None = None) -> int:
    args = parse_example_args(__doc__, argv)
    scenario = load_scenario(MAPS / "blind_corner.yaml")
    options = planner_options(args.quick)
    cache = NLPCache()
    results = [
        plan(scenario, planner, cache=cache, **options) for planner in ("secure", "baseline")
    ]
    for result in results:
        print(result.summary())
        if result.certificate is not None:
            print(f"  certificate: {result.certificate}")
    secure, baseline = results
    if secure.ok and baseline.ok:
        print(
            f"secure plan {secure.final_time:.2f} s vs baseline {baseline.final_time:.2f} s:"
            f" {secure.final_time / baseline.final_time:.2f}x (paper, planar: 2.50 s vs 1.67 s)"
        )

    claim = server_claim(scenario)
    png = top_down_figure(
        scenario.world.bounds,
        scenario.world.boxes,
        out_path=args.out / "01_blind_corner_plans.png",
        claimed_boxes=claim.boxes,
        hidden_names=scenario.hidden_obstacles,
        plans=[r for r in results if len(r.positions)],
        start=scenario.start.position,
        goal=scenario.goal.position,
        title="blind corner: secure and baseline plans",
    )
    print(f"wrote {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
