"""The same campaign variants flown by two source trees, paired variant by variant: did a change
move the outcomes, the solver's work or the flight times over a family of scenes, and by more
than chance?

A change to the planner moves IPOPT's iteration counts both ways from scene to scene (the NLP is
non-convex: a start a millimetre off can take a solve from 25 to 50 iterations), so one map, or
the 23 in ``maps/``, cannot tell a real gain from a shuffle. This flies ``-n`` variants of each
``BASE:KIND`` pair (the variants and camera seeds of ``secure3d campaign BASE --kind KIND --seed
S``, secure planner) with the ``--before`` and the ``--after`` tree, each a whole source tree (a
``git worktree`` of the base commit, say) at or after the commit that records
``SimResult.plan_iterations``. The two trees fly at once, one process each, so both see the same
load. Per pair and over all:

- outcomes: variants that changed (goal, collision, time-out), collisions in each tree;
- IPOPT iterations of all of a run's plan calls: summed, and the variants with fewer / more, with
  the two-sided sign test's p-value over them (p < 0.05: unlikely under "no effect"). Iterations
  are the same on every machine for the same code, so they judge a change to the solves, except
  in calls that a wall-clock limit stops (an A/A run: 7 of 8 variants equal, the eighth, 7 calls
  of ~6.6 s, 2,386 against 2,378);
- plan-call wall time: summed, and the median of the per-variant ratios after / before, with the
  variants faster / slower by more than ``--tie`` (15 %: two flights of the same tree moved single
  runs by 0.78-1.18x and whole campaigns by up to 1.37x on the 2-core VM);
- time to the goal (simulated) of the variants both trees brought there.

Run::

    git worktree add /tmp/before HEAD
    .venv/bin/python benchmarks/ab_campaign.py --before /tmp/before --after . \\
        forest:thin blind_corner:occlusion3d geb079_hidden_crate:fence -n 10 --seed 7
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from _common import REPO, atomic_write_text, fmt, machine_info, markdown_table

#: Relative change of a run's plan-call time within which before and after count as a tie. The
#: same tree flown twice (campaigns of 12 forest thin and 11 blind_corner occlusion3d variants, 2
#: workers on the 2-core VM) moved single runs by 0.78-1.18x and a whole campaign by 1.06-1.37x.
DEFAULT_TIE = 0.15


#: Flies a campaign's variants with the tree on ``sys.argv[1]`` (checked to be what imports):
#: one JSON line per run, as it ends.
_FLY = """
import json, sys
import secure3d
from secure3d.errors import Secure3DError
from secure3d.simulation.campaign_run import campaign_family
from secure3d.world import load_scenario
from secure3d.world.families import variant_rng
from secure3d.simulation.results import SimResult
assert secure3d.__file__.startswith(sys.argv[1]), secure3d.__file__
if not hasattr(SimResult, "plan_iterations"):
    sys.exit(f"{sys.argv[1]}: its SimResult has no plan_iterations (a tree before session 53)")
spec = json.loads(sys.argv[2])
seed = spec["seed"]
for pair in spec["pairs"]:
    base_name, kind = pair.split(":")
    base = load_scenario(base_name)
    family = campaign_family(base, kind, 1, {})
    prepared = family.prepare(base)
    for i in range(spec["n"]):
        row = {"pair": pair, "variant": i}
        try:
            scenario = family.variant(prepared, base, variant_rng(seed, i), i)
            run = secure3d.simulate(scenario, "secure", seed=seed + i,
                                    plan_budget=spec["plan_budget"],
                                    replan_defer=spec["replan_defer"])
            row.update(outcome=run.outcome, collided=bool(run.collided),
                       reached_goal=bool(run.reached_goal), time_to_goal=run.time_to_goal,
                       plan_seconds=float(sum(run.solve_times)),
                       iterations=int(sum(run.plan_iterations)), calls=len(run.solve_times),
                       flight=float(run.flight_time), sim=float(run.sim_time))
        except Secure3DError as exc:
            row.update(outcome=f"error: {type(exc).__name__}: {exc}"[:120], collided=False,
                       reached_goal=False, time_to_goal=None, plan_seconds=0.0, iterations=0,
                       calls=0, flight=0.0, sim=0.0)
        print(json.dumps(row), flush=True)
"""


def fly_both(trees: dict[str, Path], args: argparse.Namespace, work: Path) -> dict[str, dict]:
    """Every variant of ``args.pairs`` flown by each tree, the trees at once (one process each, so
    both see the same load): per tree, the runs by ``(pair, variant)``."""
    spec = json.dumps(
        {
            "pairs": args.pairs,
            "n": args.n,
            "seed": args.seed,
            "plan_budget": args.plan_budget,
            "replan_defer": args.replan_defer,
        }
    )
    work.mkdir(parents=True, exist_ok=True)
    procs = {}
    for label, tree in trees.items():
        tree = tree.resolve()
        env = dict(os.environ, PYTHONPATH=str(tree))
        log = (work / f"{label}.jsonl").open("w")
        # in the tree: the working directory comes first on sys.path
        procs[label] = (
            subprocess.Popen(
                [sys.executable, "-c", _FLY, str(tree), spec],
                cwd=tree,
                env=env,
                stdout=log,
                stderr=subprocess.PIPE,
                text=True,
            ),
            log,
        )
    _progress(procs, work, len(args.pairs) * args.n)
    for label, (proc, log) in procs.items():
        _, err = proc.communicate()
        log.close()
        if proc.returncode:
            tail = err.strip().splitlines()[-1:] if err else []
            raise SystemExit(f"{label} tree ({trees[label]}): the flights stopped: {tail}")
    return {label: read_runs(work / f"{label}.jsonl") for label in trees}


def _progress(procs: dict, work: Path, total: int, every: float = 5.0) -> None:
    """Until both trees' processes end, a line on stderr whenever their count of runs moved; once
    one tree's process fails, the other is stopped (its comparison is lost anyway)."""
    last = None
    while any(proc.poll() is None for proc, _ in procs.values()):
        if any(proc.poll() not in (None, 0) for proc, _ in procs.values()):
            for proc, _ in procs.values():
                if proc.poll() is None:
                    proc.terminate()
            return
        time.sleep(every)
        done = {label: _lines(work / f"{label}.jsonl") for label in procs}
        if done != last:
            runs = ", ".join(f"{label} {n}/{total}" for label, n in done.items())
            print(f"flown: {runs}", file=sys.stderr, flush=True)
            last = done


def _lines(path: Path) -> int:
    """Complete lines in ``path`` so far (0 if it is not there yet)."""
    try:
        return path.read_text().count("\n")
    except FileNotFoundError:
        return 0


def read_runs(path: Path) -> dict[tuple[str, int], dict]:
    """One tree's runs (JSON lines) by ``(pair, variant)``."""
    rows = [json.loads(ln) for ln in path.read_text().splitlines() if ln.strip()]
    return {(r["pair"], int(r["variant"])): r for r in rows}


def sign_test(wins: int, losses: int) -> float:
    """Two-sided p-value of ``wins`` against ``losses`` under the null "each equally likely"."""
    n = wins + losses
    if n == 0:
        return 1.0
    k = min(wins, losses)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2**n
    return min(1.0, 2.0 * tail)


def paired(before: dict, after: dict, tie: float) -> dict[str, object]:
    """Paired figures of two trees' runs (their common keys): outcome changes, collisions and
    arrivals, IPOPT iterations (deterministic: every difference counts), plan-call seconds (wall:
    changes within ``tie`` count as ties) and the change of the time to the goal."""
    common = sorted(set(before) & set(after))
    changed = [v for v in common if before[v]["outcome"] != after[v]["outcome"]]
    ib = np.array([before[v]["iterations"] for v in common], dtype=float)
    ia = np.array([after[v]["iterations"] for v in common], dtype=float)
    pb = np.array([before[v]["plan_seconds"] for v in common])
    pa = np.array([after[v]["plan_seconds"] for v in common])
    ratio = pa / np.maximum(pb, 1e-9)
    both = [v for v in common if before[v]["reached_goal"] and after[v]["reached_goal"]]
    ttg = np.array([after[v]["time_to_goal"] - before[v]["time_to_goal"] for v in both])
    fewer, more = int((ia < ib).sum()), int((ia > ib).sum())
    return {
        "variants": len(common),
        "changed": changed,
        "collisions": tuple(sum(bool(r[v]["collided"]) for v in common) for r in (before, after)),
        "at goal": tuple(sum(bool(r[v]["reached_goal"]) for v in common) for r in (before, after)),
        "iterations": (int(ib.sum()), int(ia.sum())),
        "fewer": fewer,
        "more": more,
        "p": sign_test(fewer, more),
        "plan": (float(pb.sum()), float(pa.sum())),
        "median ratio": float(np.median(ratio)) if len(ratio) else float("nan"),
        "faster": int((ratio < 1.0 - tie).sum()),
        "slower": int((ratio > 1.0 + tie).sum()),
        "ttg": (float(ttg.mean()) if len(ttg) else float("nan"), int((np.abs(ttg) > 1e-6).sum())),
    }


def row_of(label: str, d: dict[str, object]) -> list[str]:
    """A markdown row of :func:`paired`'s figures."""
    (cb, ca), (gb, ga) = d["collisions"], d["at goal"]
    (ib, ia), (pb, pa) = d["iterations"], d["plan"]
    ttg_mean, ttg_moved = d["ttg"]
    return [
        label,
        str(d["variants"]),
        f"{cb} / {ca}",
        f"{gb} / {ga}",
        str(len(d["changed"])),
        f"{ib} -> {ia}",
        f"{d['fewer']} / {d['more']}",
        fmt(d["p"], 3),
        f"{fmt(pb, 1)} -> {fmt(pa, 1)}",
        f"{fmt(d['median ratio'], 3)} ({d['faster']} / {d['slower']})",
        f"{fmt(ttg_mean, 3)} ({ttg_moved} moved)",
    ]


HEAD = [
    "base:kind",
    "variants",
    "collisions before / after",
    "at goal before / after",
    "outcome changed",
    "IPOPT iterations before -> after",
    "fewer / more",
    "sign test p",
    "plan calls (s) before -> after",
    "median time ratio (faster / slower)",
    "time to goal, mean change (s)",
]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pairs", nargs="+", help="BASE:KIND (a shipped scenario or a YAML file)")
    ap.add_argument("--before", type=Path, required=True, help="source tree before the change")
    ap.add_argument("--after", type=Path, default=REPO, help="source tree after the change")
    ap.add_argument("-n", type=int, default=10, help="variants per pair (10)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--plan-budget", type=float, default=10.0)
    ap.add_argument("--replan-defer", type=float, default=0.5, help="as the campaign's (0.5 s)")
    ap.add_argument("--tie", type=float, default=DEFAULT_TIE)
    ap.add_argument("--work", type=Path, default=Path("out/ab_campaign"))
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks/results/ab_campaign.md")
    args = ap.parse_args()
    from secure3d.world.family_registry import FAMILIES

    kinds = ("auto", "corner", "forest", *FAMILIES)
    for pair in args.pairs:
        if pair.count(":") != 1:
            raise SystemExit(f"{pair}: expected BASE:KIND, e.g. forest:thin")
        if pair.split(":")[1] not in kinds:
            raise SystemExit(f"{pair}: KIND must be one of {', '.join(kinds)}")
    if args.n < 1 or not args.tie >= 0 or not args.plan_budget > 0:
        raise SystemExit(
            f"-n must be >= 1, --tie >= 0 and --plan-budget > 0 (got {args.n}, {args.tie},"
            f" {args.plan_budget})"
        )
    for label, tree in (("--before", args.before), ("--after", args.after)):
        if not (tree / "secure3d" / "__init__.py").is_file():
            raise SystemExit(f"{label} {tree}: not a source tree (no secure3d/__init__.py)")
    t0, load0, info = time.perf_counter(), os.getloadavg()[0], machine_info()
    runs = fly_both({"before": args.before, "after": args.after}, args, args.work.resolve())
    before, after = runs["before"], runs["after"]
    rows, notes = [], []
    for pair in args.pairs:
        mine = [key for key in before if key[0] == pair]
        d = paired(
            {k: before[k] for k in mine}, {k: after[k] for k in mine if k in after}, args.tie
        )
        rows.append(row_of(pair, d))
        notes += [
            f"- {k[0]} variant {k[1]}: {before[k]['outcome']} -> {after[k]['outcome']}"
            for k in d["changed"]
        ]
    rows.append(row_of("**all**", paired(before, after, args.tie)))
    command = "benchmarks/ab_campaign.py " + " ".join(sys.argv[1:])
    text = "\n".join(
        [
            "# The same campaign variants flown by two source trees, paired by variant",
            "",
            f"Command: `{command}`",
            "",
            f"Machine: `{info}`; before: `{args.before}`, after: `{args.after}`, flown at once "
            f"(one process each); {time.perf_counter() - t0:.0f} s, load (1-min average) "
            f"{load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end.",
            "",
            markdown_table(HEAD, rows),
            "",
            "IPOPT iterations: of all of a run's plan calls, summed over the variants; fewer / "
            "more: variants whose count fell / rose (deterministic); sign test: two-sided, over "
            f"those. Plan calls: wall time; a run's time ratio within {args.tie:.0%} is a tie. "
            "Time to goal: over the variants both trees brought to the goal.",
            "",
            *(["Outcomes that changed:", "", *notes, ""] if notes else []),
        ]
    )
    print(text)
    print(f"wrote {atomic_write_text(args.out, text)}")


if __name__ == "__main__":
    main()
