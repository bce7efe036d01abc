"""The closed loop's wall time outside the planner, before and after a change, side by side (issue 18).

A flight's wall time is its plan calls (``SimResult.solve_times``: guess, solves, certificate of
each plan) and the rest: camera frames, map updates, obstacle boxes, re-certification, the tracking
guard, tracking, integration, collision checks. This benchmark flies every scenario of ``maps/``
with two source trees in turn (``--before`` and ``--after``, each a checkout whose ``secure3d``
package is imported through ``PYTHONPATH``), one new process per flight, alternating the trees per
scenario so that both see the same load. Per scenario and tree: the outcome (it must not change),
simulated time, flight wall time, plan-call time and the rest, and the real-time factors.

Run (the ``before`` tree is a ``git worktree`` of the older commit)::

    .venv/bin/python benchmarks/bench_non_plan.py --before ../old --after . \\
        --out benchmarks/results/non_plan.md
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from _common import REPO, atomic_write_text, fmt, machine_info, markdown_table, python_json

_FLY = """
import json, sys
import secure3d
assert secure3d.__file__.startswith(sys.argv[3]), secure3d.__file__
out = {}
for planner in sys.argv[2].split(","):
    run = secure3d.simulate(sys.argv[1], planner, seed=0)
    plan = float(sum(run.solve_times))
    out[planner] = {"outcome": run.outcome, "collided": bool(run.collided),
                    "sim": float(run.sim_time), "flight": float(run.flight_time), "plan": plan,
                    "rest": float(run.flight_time) - plan}
print(json.dumps(out))
"""


def fly(tree: Path, scenario: Path, planners: str) -> dict:
    """Every planner's flight of ``scenario`` with the package of ``tree``, in a new process."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    # run in the tree: ``-c`` puts the working folder first on sys.path
    return python_json(_FLY, [str(scenario.resolve()), planners, str(tree)], tree, env)


def rows(results: dict, planner: str) -> list[list[str]]:
    """Table rows: scenario, outcome (same?), simulated, plan calls and rest before/after, the
    rest's ratio, RTFs."""
    out = []
    for name, r in results.items():
        b, a = r["before"].get(planner), r["after"].get(planner)
        if b is None or a is None:
            out.append([name, "error", "", "", "", "", "", "", "", ""])
            continue
        same = b["outcome"] == a["outcome"] and abs(b["sim"] - a["sim"]) < 1e-9
        out.append(
            [
                name,
                a["outcome"] + ("" if same else f" (before: {b['outcome']}, {b['sim']:.2f} s)"),
                fmt(a["sim"]),
                fmt(b["plan"]),
                fmt(a["plan"]),
                fmt(b["rest"]),
                fmt(a["rest"]),
                fmt(b["rest"] / max(a["rest"], 1e-9)),
                fmt(b["sim"] / b["flight"]),
                fmt(a["sim"] / a["flight"]),
            ]
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", type=Path, required=True, help="source tree before the change")
    ap.add_argument("--after", type=Path, default=REPO, help="source tree after the change")
    ap.add_argument("--planners", default="secure,baseline")
    ap.add_argument("--only", nargs="*", help="scenario names (default: every maps/*.yaml)")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks/results/non_plan.md")
    args = ap.parse_args()
    scenarios = sorted((REPO / "maps").glob("*.yaml"))
    if args.only:
        scenarios = [s for s in scenarios if s.stem in args.only]
    results: dict = {}
    t0, load0 = time.perf_counter(), os.getloadavg()[0]
    for k, sc in enumerate(scenarios):
        trees = [("before", args.before), ("after", args.after)]
        if k % 2:  # alternate which tree flies first
            trees.reverse()
        results[sc.stem] = {label: fly(tree.resolve(), sc, args.planners) for label, tree in trees}
        print(sc.stem, json.dumps(results[sc.stem]), file=sys.stderr, flush=True)
    head = [
        "scenario",
        "outcome (after)",
        "simulated (s)",
        "plan calls before (s)",
        "plan calls after (s)",
        "rest before (s)",
        "rest after (s)",
        "rest ratio",
        "RTF before",
        "RTF after",
    ]
    text = [
        "# Closed-loop wall time outside the planner, before and after (issue 18)",
        "",
        "Command: `.venv/bin/python benchmarks/bench_non_plan.py " + " ".join(sys.argv[1:]) + "`",
        "",
        f"Machine: `{json.dumps(machine_info())}`; {len(scenarios)} scenarios in"
        f" {time.perf_counter() - t0:.0f} s; load (1-min average) {load0:.2f} at the start,"
        f" {os.getloadavg()[0]:.2f} at the end.",
        "",
        "*rest* = flight wall time minus the plan calls (`SimResult.solve_times`); RTF = simulated"
        " time / flight wall time (plan calls included). One flight per tree and scenario (seed 0),"
        " each in a new process, the two trees alternating.",
        "",
    ]
    for planner in args.planners.split(","):
        text += [f"## {planner}", "", markdown_table(head, rows(results, planner)), ""]
    text += ["Raw figures:", "", "```json", json.dumps(results, indent=1), "```", ""]
    atomic_write_text(args.out, "\n".join(text))
    print(args.out)


if __name__ == "__main__":
    main()
