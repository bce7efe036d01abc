"""One whole secure ``plan()`` call on the real scans against the blind corner's (issue 17's
target: at most 3x), side by side in one process.

Every scenario plans on its server's map with one NLP cache: one warm-up call each (NLPs
compiled, kernels loaded), then ``--reps`` calls of each, interleaved, so that the machine's load
falls on all of them alike. Each call is the whole of ``secure3d.plan``: guess, solves, slot
refreshes, look-back rounds and certificate; a plan that is not certified stops the benchmark.
Run::

    .venv/bin/python benchmarks/bench_plan_ratio.py [--reps 5] [--out results/plan_ratio.md]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from _common import REPO, atomic_write_text, fmt, machine_info, markdown_table

REFERENCE = "blind_corner"
SCENARIOS = ("geb079_hidden_cabinet", "geb079_hidden_crate", "geb079_region_attacks")
TARGET_RATIO = 3.0


def measure(names: list[str], reps: int) -> dict[str, dict]:
    """Per scenario: wall times of ``reps`` interleaved calls, final time and IPOPT iterations."""
    import secure3d
    from secure3d.planning.collocation import NLPCache

    scenarios = {n: secure3d.load_scenario(n) for n in names}
    cache = NLPCache()
    for n in names:
        secure3d.plan(scenarios[n], "secure", cache=cache)
    out: dict[str, dict] = {n: {"calls": []} for n in names}
    for _ in range(reps):
        for n in names:
            t0 = time.perf_counter()
            result = secure3d.plan(scenarios[n], "secure", cache=cache)
            out[n]["calls"].append(time.perf_counter() - t0)
            if not (result.ok and result.certificate is not None and result.certificate.ok):
                raise SystemExit(f"{n}: the plan was not certified ({result.status.value})")
            out[n]["final_time"], out[n]["iterations"] = result.final_time, result.iterations
    return out


def report(data: dict[str, dict], reps: int, command: str) -> str:
    """The markdown table of medians and ratios to the reference."""
    ref = float(np.median(data[REFERENCE]["calls"]))
    rows = []
    for n, d in data.items():
        med = float(np.median(d["calls"]))
        ratio = med / ref
        mark = "" if n == REFERENCE or ratio <= TARGET_RATIO else " (over)"
        rows.append(
            [
                n,
                fmt(med, 3),
                f"{ratio:.2f}x{mark}",
                d["iterations"],
                fmt(d["final_time"], 3),
                " ".join(fmt(c, 3) for c in d["calls"]),
            ]
        )
    table = markdown_table(
        [
            "scenario",
            "median call (s)",
            f"ratio to {REFERENCE}",
            "IPOPT iterations",
            "T (s)",
            "calls (s)",
        ],
        rows,
    )
    return (
        f"# One secure plan() call against {REFERENCE}'s (issue 17: at most {TARGET_RATIO:g}x)\n\n"
        f"Command: `{command}`\n\nMachine: `{json.dumps(machine_info())}`; {reps} interleaved "
        "calls per scenario after one warm-up call each, one NLP cache, every plan certified.\n\n"
        f"{table}\n"
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--out", default=None, help="markdown file (default: print only)")
    args = ap.parse_args()
    if args.reps < 1:
        ap.error(f"--reps: must be at least 1, got {args.reps}")
    names = [REFERENCE, *[n for n in args.scenarios if n != REFERENCE]]
    text = report(measure(names, args.reps), args.reps, " ".join(["python", *sys.argv]))
    print(text)
    if args.out:
        path = atomic_write_text(REPO / "benchmarks" / args.out, text)
        print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
