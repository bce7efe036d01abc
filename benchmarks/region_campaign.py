"""A small region-attack campaign over a scenario (issue 24), run directly through the family.

    PYTHONPATH=. .venv/bin/python benchmarks/region_campaign.py [SCENARIO] [N] [SEED] [PLANNERS] [FIRST]

Default: maps/geb079_region_attacks.yaml, 20 variants, seed 0, secure only. Variant i is
``REGION_ATTACKS.variant(prepare(base), base, default_rng(SeedSequence(seed, spawn_key=(i,))), i)``.
Prints one row per run and writes benchmarks/results/region_campaign_<scenario>.md.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str]) -> int:
    from secure3d.simulation.closed_loop import simulate
    from secure3d.world import load_scenario
    from secure3d.world.region_attacks import REGION_ATTACKS, variant_rng

    path = Path(argv[0]) if argv else ROOT / "maps" / "geb079_region_attacks.yaml"
    n = int(argv[1]) if len(argv) > 1 else 20
    seed = int(argv[2]) if len(argv) > 2 else 0
    planners = argv[3].split(",") if len(argv) > 3 else ["secure"]
    first = int(argv[4]) if len(argv) > 4 else 0
    base = load_scenario(path)
    prep = REGION_ATTACKS.prepare(base)
    rows = [
        "| variant | attack | planner | collided | reached goal | time to goal (s) |"
        " min clearance (m) | wall (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    stats: dict[str, list[int]] = {p: [0, 0, 0] for p in planners}  # runs, collisions, goals
    for i in range(first, n):
        v = REGION_ATTACKS.variant(prep, base, variant_rng(seed, i), i)
        for planner in planners:
            t0 = time.perf_counter()
            r = simulate(v, planner=planner, seed=0)
            ttg = f"{r.time_to_goal:.2f}" if r.time_to_goal is not None else "-"
            row = (
                f"| {i} | {v.server_map.attacks[-1].describe()} | {planner} | {r.collided} |"
                f" {r.reached_goal} | {ttg} | {r.min_clearance:.3f} |"
                f" {time.perf_counter() - t0:.0f} |"
            )
            print(row, flush=True)
            rows.append(row)
            s = stats[planner]
            s[0] += 1
            s[1] += int(r.collided)
            s[2] += int(r.reached_goal)
    summary = [
        f"- {p}: {s[0]} runs, {s[1]} collisions, goal rate {s[2]}/{s[0]}" for p, s in stats.items()
    ]
    print("\n".join(summary))
    part = f"_from{first}" if first else ""
    out = ROOT / "benchmarks" / "results" / f"region_campaign_{base.name}{part}.md"
    out.write_text(
        f"# Region-attack campaign over {path.name} (seed {seed}, variants {first}-{n - 1})\n\n"
        + "\n".join(summary)
        + "\n\n"
        + "\n".join(rows)
        + "\n"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
