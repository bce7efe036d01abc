"""Fly variants of the issue-16 families (thin obstacles, 3D occlusion) in closed loop.

For each base scenario and family, variants ``0 .. n-1`` (variant i drawn from
``SeedSequence(seed, spawn_key=(i,))``, as campaigns do) are flown by each planner; a row per
flight and a tally per family and planner (collisions, goal rate) are printed and written as
markdown. Flights are capped in simulated time (``--time-limit``) and plan calls in wall time
(``--solve-limit``) so a stall costs seconds, not minutes. Run::

    .venv/bin/python benchmarks/fly_thin_families.py --bases thin_pole,blind_corner -n 10 \
        [--families thin,occlusion3d] [--out results/thin_families.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np
from _common import REPO, atomic_write_text, markdown_table

import secure3d
from secure3d.planning.collocation import NLPCache
from secure3d.simulation.closed_loop import simulate
from secure3d.world.thin_families import OCCLUSION_3D, THIN_OBSTACLES

FAMILIES = {f.name: f for f in (THIN_OBSTACLES, OCCLUSION_3D)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bases", default="thin_pole,blind_corner")
    ap.add_argument("--families", default="thin,occlusion3d")
    ap.add_argument("-n", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--planners", default="secure,baseline")
    ap.add_argument("--time-limit", type=float, default=25.0, help="simulated s per flight")
    ap.add_argument("--solve-limit", type=float, default=10.0, help="wall s per plan call")
    ap.add_argument("--max-replans", type=int, default=10)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    rows, tally = [], {}
    cache = NLPCache()
    for base_name in args.bases.split(","):
        base = secure3d.load_scenario(REPO / "maps" / f"{base_name}.yaml")
        base = dataclasses.replace(
            base, simulation=dataclasses.replace(base.simulation, time_limit=args.time_limit)
        )
        for fam_name in args.families.split(","):
            fam = FAMILIES[fam_name]
            prep = fam.prepare(base)
            for i in range(args.n):
                rng = np.random.default_rng(np.random.SeedSequence(args.seed, spawn_key=(i,)))
                v = fam.variant(prep, base, rng, i)
                hidden = v.world.boxes[-1]
                for planner in args.planners.split(","):
                    t0 = time.perf_counter()
                    run = simulate(
                        v,
                        planner,
                        seed=i,
                        cache=cache,
                        max_replans=args.max_replans,
                        time_limit=args.solve_limit,
                    )
                    wall = time.perf_counter() - t0
                    key = (base_name, fam_name, planner)
                    t = tally.setdefault(key, [0, 0, 0])
                    t[0] += 1
                    t[1] += run.collided
                    t[2] += run.reached_goal
                    rows.append(
                        [
                            v.name,
                            hidden.name,
                            planner,
                            run.outcome,
                            f"{run.sim_time:.1f}",
                            f"{wall:.1f}",
                        ]
                    )
                    print(" | ".join(rows[-1]), flush=True)
    summary = [
        [b, f, p, str(n), str(c), f"{g}/{n}"] for (b, f, p), (n, c, g) in sorted(tally.items())
    ]
    text = (
        "## Flights\n\n"
        + markdown_table(["variant", "hidden", "planner", "outcome", "sim s", "wall s"], rows)
        + "\n\n## Tally\n\n"
        + markdown_table(["base", "family", "planner", "runs", "collisions", "goal"], summary)
        + "\n"
    )
    print(text)
    if args.out is not None:
        atomic_write_text(args.out, text)


if __name__ == "__main__":
    main()
