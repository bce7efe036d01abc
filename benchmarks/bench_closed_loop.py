"""How fast the closed loop (the paper's Algorithm 1) runs, and where its wall time goes (issue #6).

For each scenario and planner, ``--reps`` flights (same seed: same outcome, timing varies) with one
NLP cache per repetition, so every flight pays its own NLP builds, as ``make demo`` does; then
``--reps`` more with the compiled NLPs already cached (after one flight that builds them), as every
flight after the first in a campaign worker or any long-lived process. Reported per case
(medians): the outcome, simulated time, wall time and real-time factor (simulated / wall) both
ways, and the fresh flights' wall time split into

- *plan calls*: every ``plan_problem`` call of the flight (graph-search guess, NLP builds, solves,
  slot re-selections, certificate), with *build* (NLP compilation) shown separately;
- *rest*: everything else (world set-up, ray-cast frames, map insertion, re-certifications,
  tracking, integration, FCL checks).

The issue's target is a real-time factor of at least 5 on the blind corner. Run::

    .venv/bin/python benchmarks/bench_closed_loop.py [--reps 3] [--out results/closed_loop.md]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from _common import REPO, atomic_write_json, atomic_write_text, fmt, machine_info, markdown_table
from tqdm import tqdm

SCENARIOS = ("blind_corner", "blind_corner_quadrotor")
PLANNERS = ("secure", "baseline")
TARGET_RTF = 5.0


def fly(scenario_path: Path, planner: str, seed: int, cache: object = None) -> dict:
    """One flight (with a fresh NLP cache unless given one): outcome and the wall-time split."""
    import secure3d
    from secure3d.planning.collocation import NLPCache

    cache = NLPCache() if cache is None else cache
    run = secure3d.simulate(scenario_path, planner, seed=seed, cache=cache)
    plan_wall = float(sum(run.solve_times))
    build = float(sum(p.build_time for _, p in run.plans))
    return {
        "outcome": run.outcome,
        "sim": float(run.sim_time),
        "wall": float(run.wall_time),
        "rtf": float(run.real_time_factor),
        "plan_calls": len(run.solve_times),
        "plan_wall": plan_wall,
        "build": build,
        "rest": float(run.wall_time) - plan_wall,
        "frames": int(run.frames),
        "replans": int(run.replans),
        "takeovers": int(run.takeovers),
    }


def measure(args: argparse.Namespace) -> dict:
    cases = [(s, p) for s in args.scenarios for p in args.planners]
    machine = machine_info()
    rows = []
    from secure3d.planning.collocation import NLPCache

    with tqdm(total=len(cases) * (2 * args.reps + 1), unit="flight", desc="closed loop") as bar:
        for name, planner in cases:
            path = args.maps / f"{name}.yaml"
            reps, cached = [], []
            for _ in range(args.reps):
                bar.set_postfix_str(f"{name} {planner}")
                reps.append(fly(path, planner, args.seed))
                bar.update()
            cache = NLPCache()
            fly(path, planner, args.seed, cache)  # builds the NLPs the flights below reuse
            bar.update()
            for _ in range(args.reps):
                bar.set_postfix_str(f"{name} {planner} cached")
                cached.append(fly(path, planner, args.seed, cache))
                bar.update()
            rows.append({"scenario": name, "planner": planner, "reps": reps, "cached": cached})
    return {"settings": vars(args) | {"maps": str(args.maps)}, "machine": machine, "rows": rows}


def median(reps: list[dict], key: str) -> float:
    return float(np.median([r[key] for r in reps]))


def report(data: dict) -> str:
    m, s = data["machine"], data["settings"]
    table = []
    for row in data["rows"]:
        reps = row["reps"]
        outcomes = sorted({r["outcome"] for r in reps})
        table.append(
            [
                row["scenario"],
                row["planner"],
                " / ".join(outcomes),
                fmt(median(reps, "sim")),
                fmt(median(reps, "wall")),
                fmt(median(reps, "rtf")) + "x",
                fmt(median(row["cached"], "wall")),
                fmt(median(row["cached"], "rtf")) + "x",
                f"{median(reps, 'plan_calls'):.0f}",
                fmt(median(reps, "plan_wall")),
                fmt(median(reps, "build")),
                fmt(median(reps, "rest")),
                f"{median(reps, 'frames'):.0f}",
                f"{median(reps, 'replans'):.0f} / {median(reps, 'takeovers'):.0f}",
            ]
        )
    headers = [
        "scenario",
        "planner",
        "outcome",
        "sim (s)",
        "wall (s)",
        "real-time factor",
        "wall, NLPs cached (s)",
        "real-time factor, NLPs cached",
        "plan calls",
        "plan calls (s)",
        "of which build (s)",
        "rest (s)",
        "frames",
        "replans / take-overs",
    ]
    corner = [
        r for r in data["rows"] if r["scenario"] == "blind_corner" and r["planner"] == "secure"
    ]
    verdict = ""
    if corner:
        rtf = median(corner[0]["reps"], "rtf")
        rtf_cached = median(corner[0]["cached"], "rtf")
        met = "yes" if rtf >= TARGET_RTF else "NO"
        met_cached = "yes" if rtf_cached >= TARGET_RTF else "NO"
        verdict = (
            f"\nTarget (issue #6): secure blind-corner flight at least {TARGET_RTF:.0f}x faster than"
            f" real time. Measured {rtf:.2f}x with its own NLP builds (met: {met}), {rtf_cached:.2f}x"
            f" with the NLPs cached (met: {met_cached}).\n"
        )
    return "\n".join(
        [
            "# Closed-loop benchmark",
            "",
            f"Commit {m['commit']}{' (dirty)' if m['dirty'] else ''}, {m['date']}, {m['cpus']} CPUs,"
            f" load average {m['load_avg'][0]:.2f} before; casadi {m['casadi']}. Medians of"
            f" {s['reps']} flight(s) each way, seed {s['seed']}.",
            "",
            markdown_table(headers, table, right=[False, False, False] + [True] * 11),
            "",
            "Fresh: a new NLP cache per flight (every flight compiles its NLPs, as `make demo`);"
            " NLPs cached: the compiled NLPs of an earlier flight reused (a campaign worker after"
            " its first flight). The split is of the fresh flights. plan calls: wall time of every"
            " `plan_problem` call (guess, NLP builds, solves, certificate); rest: world set-up,"
            " camera frames, map updates, re-certification, tracking, integration and collision"
            " checks.",
            verdict,
        ]
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--maps", type=Path, default=REPO / "maps", help="scenario folder")
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), metavar="NAME")
    p.add_argument("--planners", nargs="+", choices=PLANNERS, default=list(PLANNERS))
    p.add_argument("--reps", type=int, default=3, help="flights per case (median reported)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, help="write the markdown report here (and FILE.json)")
    args = p.parse_args(argv)
    if args.reps < 1:
        p.error(f"--reps: must be at least 1 (got {args.reps})")
    for name in args.scenarios:
        if not (args.maps / f"{name}.yaml").is_file():
            p.error(f"--scenarios: no {name}.yaml in {args.maps}")
    data = measure(args)
    text = report(data)
    print(text)
    if args.out is not None:
        atomic_write_text(args.out, text + "\n")
        atomic_write_json(args.out.with_suffix(".json"), data)
        print(f"wrote {args.out} and {args.out.with_suffix('.json')}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
