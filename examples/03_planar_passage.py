"""03 - The paper's narrow passages with the differential-drive robot: 50 cm vs 20 cm.

The scenarios are the paper's set-up (``maps/paper_passage_*.yaml``); ``08_paper.py`` runs them
together with the paper's other experiments.

Nothing is hidden here: the point is the price of the reactive-set constraint alone. Entering at
1 m/s, the secure planner must slow inside the passage until the reactive set S_r(x) (which grows
with speed, eq. ReactEllipse) fits between the walls; the narrower the passage, the slower. The
paper reports 1.60 s through the 50 cm passage and 2.12 s through the 20 cm one; the baseline,
which only keeps the body off the walls, is shown for reference. Writes a top-down figure per
passage.

Run headless::

    .venv/bin/python examples/03_planar_passage.py [--quick] [--out out/examples]
"""

from __future__ import annotations

import sys
from pathlib import Path

from secure3d.planning import NLPCache, plan
from secure3d.viz.figures import top_down_figure
from secure3d.world import load_scenario

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import MAPS, parse_example_args, planner_options

#: Final times (s) of the paper's secure planner through each passage (its Fig. ThreadNeedle).
PAPER = {"paper_passage_50cm": 1.60, "paper_passage_20cm": 2.12}


def main(argv: list[str] | None = None) -> int:
    args = parse_example_args(__doc__, argv)
    options = planner_options(args.quick)
    cache = NLPCache()
    print(f"{'passage':<22} {'planner':<9} {'status':<15} {'final time':>10}  paper")
    for name, paper_time in PAPER.items():
        scenario = load_scenario(MAPS / f"{name}.yaml")
        results = [plan(scenario, p, cache=cache, **options) for p in ("secure", "baseline")]
        for r in results:
            t = f"{r.final_time:.2f} s" if r.ok else "-"
            paper = f"{paper_time:.2f} s" if r.planner == "secure" else ""
            print(f"{name:<22} {r.planner:<9} {r.status.value:<15} {t:>10}  {paper}")
        png = top_down_figure(
            scenario.world.bounds,
            scenario.world.boxes,
            out_path=args.out / f"03_{name}.png",
            plans=[r for r in results if len(r.positions)],
            start=scenario.start.position,
            goal=scenario.goal.position,
            title=f"{name}: secure and baseline plans",
        )
        print(f"wrote {png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
