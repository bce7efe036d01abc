"""The node kernels' derivatives compiled to C against CasADi's VM: evaluation, cold plans, flights.

Three measurements, all in one cache folder of compiled kernels (``--cache``, default a new
temporary folder, so that the first sight of every kernel shape pays its compile):

1. **First sight** (``now`` mode): every scenario flown once in a new process, compiling what its
   NLPs need; wall time, libraries added, and the outcome (it must equal the VM's).
2. **Evaluation** (``--eval``, one process): the closed loop's NLP of each named scenario (cold
   plan, 12 obstacle slots) built with the VM's and with the compiled kernels; the Lagrangian
   Hessian and constraint Jacobian timed alternately, and their values compared.
3. **Flights** (``--rounds`` R): every scenario flown ``off`` and ``now`` (libraries present),
   one new process per flight, the modes alternating; medians over the rounds of the plan calls,
   the flight and the real-time factor, with each flight's outcome, simulated time and IPOPT
   iterations (which must not change).

Run::

    .venv/bin/python benchmarks/bench_compiled_kernels.py --rounds 2 \\
        --out benchmarks/results/compiled_kernels.md
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from _common import REPO, atomic_write_text, fmt, machine_info, markdown_table, python_json

_FLY = """
import json, sys, time
import secure3d
import secure3d.planning.solve as S
import secure3d.planning.slot_refresh as R
from secure3d.planning import compiled_kernels
its = []
orig = S._solve_once
def spy(*a, **k):
    s = orig(*a, **k); its.append(s.iterations); return s
S._solve_once = R._solve_once = spy
t = time.perf_counter()
run = secure3d.simulate(sys.argv[1], "secure", seed=0)
wall = time.perf_counter() - t
print(json.dumps({"outcome": run.outcome, "sim": float(run.sim_time), "flight": float(run.flight_time),
                  "plan": float(sum(run.solve_times)), "its": sum(its), "wall": wall,
                  "loaded": compiled_kernels.status()["loaded"]}))
"""

_EVAL = """
import json, os, sys, time
import numpy as np
from secure3d.planning import NLPCache, plan_problem, problem_from_scenario
from secure3d.world import load_scenario
problem = problem_from_scenario(load_scenario(sys.argv[1]), obstacle_slots=12)
fns = {}
for how in ("off", "now"):
    os.environ["SECURE3D_KERNEL_COMPILE"] = how
    cache = NLPCache()
    plan_problem(problem, "secure", cache=cache)
    nlp = list(cache._items.values())[-1][0]
    fns[how] = (nlp.solver_options["hess_lag"], nlp.solver_options["jac_g"])
H = fns["off"][0]
rng = np.random.default_rng(0)
x = rng.normal(size=H.size1_in(0)) * 0.1
p = np.zeros(H.size1_in(1))
lam = rng.normal(size=H.size1_in(3))
def per_call(f, args, n=20):
    t = time.perf_counter()
    for _ in range(n):
        f(*args)
    return (time.perf_counter() - t) / n * 1e3
times = {how: {"hess": [], "jac": []} for how in fns}
for _ in range(7):
    for how, (h, j) in fns.items():
        times[how]["hess"].append(per_call(h, [x, p, 1.0, lam]))
        times[how]["jac"].append(per_call(j, [x, p]))
same = all(
    np.array_equal(np.array(a.nonzeros()), np.array(b.nonzeros()))
    for a, b in zip(fns["off"][0].call([x, p, 1.0, lam]) + fns["off"][1].call([x, p]),
                    fns["now"][0].call([x, p, 1.0, lam]) + fns["now"][1].call([x, p]))
)
med = {how: {k: float(np.median(v)) for k, v in d.items()} for how, d in times.items()}
print(json.dumps({"variables": int(H.size1_in(0)), "hessian_nonzeros": int(H.sparsity_out(0).nnz()),
                  "times": med, "same": bool(same)}))
"""


def _run(code: str, scenario: Path, how: str, cache: Path) -> dict:
    env = dict(
        os.environ,
        PYTHONPATH=str(REPO),
        SECURE3D_KERNEL_COMPILE=how,
        SECURE3D_KERNEL_CACHE_DIR=str(cache),
    )
    return python_json(code, [str(scenario.resolve())], REPO, env)


def _libraries(cache: Path) -> int:
    return len(list(cache.glob("*.so"))) if cache.is_dir() else 0


def first_sight(scenarios: list[Path], cache: Path) -> dict:
    """Every scenario flown once in ``now`` mode: compiles what is missing from ``cache``."""
    out = {}
    for sc in scenarios:
        before = _libraries(cache)
        out[sc.stem] = dict(_run(_FLY, sc, "now", cache), added=_libraries(cache) - before)
        print("first sight", sc.stem, json.dumps(out[sc.stem]), file=sys.stderr, flush=True)
    return out


def flights(scenarios: list[Path], cache: Path, rounds: int) -> dict:
    """``rounds`` flights per scenario and mode, alternating."""
    out: dict = {sc.stem: {"off": [], "now": []} for sc in scenarios}
    for r in range(rounds):
        for k, sc in enumerate(scenarios):
            modes = ["off", "now"] if (k + r) % 2 == 0 else ["now", "off"]
            for how in modes:
                out[sc.stem][how].append(_run(_FLY, sc, how, cache))
            print(
                "round",
                r,
                sc.stem,
                json.dumps({h: out[sc.stem][h][-1] for h in modes}),
                file=sys.stderr,
                flush=True,
            )
    return out


def _median(runs: list[dict], key: str) -> float:
    return statistics.median(run[key] for run in runs)


def flight_rows(results: dict, first: dict) -> tuple[list[list[str]], dict]:
    rows, sums = [], {"plan_off": 0.0, "plan_now": 0.0, "flight_off": 0.0, "flight_now": 0.0}
    for name, r in results.items():
        runs = r["off"] + r["now"] + [first.get(name, {})]
        if any("error" in run or not run for run in runs):
            rows.append([name, "error"] + [""] * 8)
            continue
        keys = {(run["outcome"], run["sim"], run["its"]) for run in runs}
        off, now = r["off"], r["now"]
        po, pn, fo, fn_ = (
            _median(off, "plan"),
            _median(now, "plan"),
            _median(off, "flight"),
            _median(now, "flight"),
        )
        sums["plan_off"] += po
        sums["plan_now"] += pn
        sums["flight_off"] += fo
        sums["flight_now"] += fn_
        sim = off[0]["sim"]
        rows.append(
            [
                name,
                off[0]["outcome"] + ("" if len(keys) == 1 else f" (differs: {sorted(keys)})"),
                fmt(sim),
                str(off[0]["its"]),
                fmt(po),
                fmt(pn),
                fmt(pn / po),
                fmt(sim / fo),
                fmt(sim / fn_),
                f"{first[name]['wall']:.1f} ({first[name]['added']})",
            ]
        )
    return rows, sums


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--only", nargs="*", help="scenario names (default: every maps/*.yaml)")
    ap.add_argument(
        "--eval",
        nargs="*",
        default=[
            "forest",
            "blind_corner_quadrotor",
            "geb079_hidden_cabinet",
            "planar_blind_corner",
        ],
    )
    ap.add_argument("--cache", type=Path, help="compiled kernels' folder (default: a new one)")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks/results/compiled_kernels.md")
    args = ap.parse_args()
    scenarios = sorted((REPO / "maps").glob("*.yaml"))
    if args.only:
        scenarios = [s for s in scenarios if s.stem in args.only]
    cache = args.cache or Path(tempfile.mkdtemp(prefix="secure3d-kernels-"))
    t0, load0 = time.perf_counter(), os.getloadavg()[0]
    first = first_sight(scenarios, cache)
    evals = {}
    for name in args.eval:
        evals[name] = _run(_EVAL, REPO / "maps" / f"{name}.yaml", "now", cache)
        print("eval", name, json.dumps(evals[name]), file=sys.stderr, flush=True)
    results = flights(scenarios, cache, args.rounds)
    rows, sums = flight_rows(results, first)
    eval_rows = [
        [
            name,
            str(e["variables"]),
            str(e["hessian_nonzeros"]),
            fmt(e["times"]["off"]["hess"]),
            fmt(e["times"]["now"]["hess"]),
            fmt(e["times"]["off"]["jac"]),
            fmt(e["times"]["now"]["jac"]),
            str(e["same"]),
        ]
        for name, e in evals.items()
        if "error" not in e
    ]
    text = [
        "# Node kernels compiled to C against CasADi's VM",
        "",
        "Command: `.venv/bin/python benchmarks/bench_compiled_kernels.py "
        + " ".join(sys.argv[1:])
        + "`",
        "",
        f"Machine: `{json.dumps(machine_info())}`; {time.perf_counter() - t0:.0f} s in all; load"
        f" (1-min average) {load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end;"
        f" {_libraries(cache)} libraries compiled.",
        "",
        "## Evaluation: the closed loop's NLP (cold plan, 12 slots), ms a call, medians of 7",
        "",
        markdown_table(
            [
                "scenario",
                "variables",
                "Hessian nonzeros",
                "Hessian VM",
                "Hessian C",
                "Jacobian VM",
                "Jacobian C",
                "same values",
            ],
            eval_rows,
        ),
        "",
        f"## Flights: medians of {args.rounds} rounds, a new process each, modes alternating",
        "",
        "*plan* = the plan calls' wall time (`SimResult.solve_times`); RTF = simulated time / flight"
        " wall time; *first sight* = the wall time of the first flight with an empty cache for the"
        " scenario's new kernel shapes (compiling them before use), and the libraries it added."
        " Outcome, simulated time and IPOPT iterations are compared over every flight of both"
        " modes.",
        "",
        markdown_table(
            [
                "scenario",
                "outcome",
                "simulated (s)",
                "IPOPT iterations",
                "plan VM (s)",
                "plan C (s)",
                "plan C / VM",
                "RTF VM",
                "RTF C",
                "first sight (s) (libs)",
            ],
            rows,
        ),
        "",
        f"Sums of medians: plan calls {sums['plan_off']:.2f} -> {sums['plan_now']:.2f} s"
        f" ({sums['plan_now'] / max(sums['plan_off'], 1e-9):.3f}x); flights"
        f" {sums['flight_off']:.2f} -> {sums['flight_now']:.2f} s"
        f" ({sums['flight_now'] / max(sums['flight_off'], 1e-9):.3f}x).",
        "",
        "Raw figures:",
        "",
        "```json",
        json.dumps({"first": first, "eval": evals, "flights": results}, indent=1),
        "```",
        "",
    ]
    atomic_write_text(args.out, "\n".join(text))
    print(args.out)


if __name__ == "__main__":
    main()
