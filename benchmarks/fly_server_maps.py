"""Fly the file-sourced server-map scenarios in closed loop with both planners (issue 24).

    .venv/bin/python benchmarks/fly_server_maps.py [scenario names...]

Default: maps/cloud_server.yaml and maps/mesh_server.yaml, each with the secure and the baseline
planner, seed 0. Prints one row per run and writes benchmarks/results/server_maps.md.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(names: list[str]) -> int:
    from secure3d.simulation.closed_loop import simulate

    rows = [
        "| scenario | planner | collided | reached goal | time to goal (s) | min clearance (m) "
        "| replans | wall (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name in names:
        for planner in ("secure", "baseline"):
            t0 = time.perf_counter()
            r = simulate(ROOT / "maps" / f"{name}.yaml", planner=planner, seed=0)
            wall = time.perf_counter() - t0
            ttg = f"{r.time_to_goal:.2f}" if r.time_to_goal is not None else "-"
            row = (
                f"| {name} | {planner} | {r.collided} | {r.reached_goal} | {ttg} |"
                f" {r.min_clearance:.3f} | {r.replans} | {wall:.0f} |"
            )
            print(row, flush=True)
            rows.append(row)
    out = ROOT / "benchmarks" / "results" / "server_maps.md"
    out.write_text(
        "# Server maps from files, flown in closed loop (seed 0)\n\n" + "\n".join(rows) + "\n"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:] or ["cloud_server", "mesh_server"]))
