"""Where each plan call of one campaign variant's flight spends its wall time, and whether it kept
its budget (issue 16: "no plan call over its budget").

Re-flies variant ``I`` of a campaign (``BASE``, family ``KIND``, ``--seed``, default 0: the
campaign's own variant and camera seed) with the secure planner and prints, per plan call, its
wall time, status and IPOPT iterations, and the time and count of its stages (guess, solves, slot
refreshes, certificate).
Run::

    PYTHONPATH=. .venv/bin/python benchmarks/plan_call_stages.py maps/geb079_region_attacks.yaml \\
        region_attacks 150 [--budget 10] [--seed 0]
"""

from __future__ import annotations

import argparse
import collections
import functools
import time

import secure3d
from secure3d.planning import certificate, judging, lookback, nlp_cache
from secure3d.planning import solve as solve_module
from secure3d.simulation.campaign_run import campaign_family
from secure3d.world import load_scenario
from secure3d.world.families import variant_rng
from secure3d.world.family_registry import FAMILIES

STAGES = (
    (solve_module, "initial_guess"),
    (solve_module, "_solve_once"),
    (judging, "_refresh_slots"),
    (solve_module, "_judged"),
    (solve_module, "_extra_starts"),
    (nlp_cache.NLPCache, "get"),
    (certificate, "certify"),
    (lookback, "select_slots"),
    (lookback, "slots_missing"),
)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("base")
    ap.add_argument("kind", choices=["auto", "corner", "forest", *sorted(FAMILIES)])
    ap.add_argument("variant", type=int)
    ap.add_argument("--budget", type=float, default=10.0, help="plan budget (s; 10)")
    ap.add_argument("--seed", type=int, default=0, help="the campaign's seed (0)")
    args = ap.parse_args()
    base = load_scenario(args.base)
    # the campaign's own family (its hidden obstacles leave gaps the robot's footprint passes)
    family = campaign_family(base, args.kind, 1, {})
    scenario = family.variant(
        family.prepare(base), base, variant_rng(args.seed, args.variant), args.variant
    )
    spent: dict[str, float] = collections.defaultdict(float)
    calls: collections.Counter[str] = collections.Counter()

    def timed(owner: object, name: str) -> None:
        f = getattr(owner, name)

        @functools.wraps(f)
        def g(*a: object, **k: object) -> object:
            t = time.perf_counter()
            try:
                return f(*a, **k)
            finally:
                spent[name] += time.perf_counter() - t
                calls[name] += 1

        setattr(owner, name, g)

    for owner, name in STAGES:
        timed(owner, name)
    plan_problem = solve_module.plan_problem

    def traced(*a: object, **k: object) -> object:
        spent.clear()
        calls.clear()
        t = time.perf_counter()
        r = plan_problem(*a, **k)
        wall = time.perf_counter() - t
        stages = ", ".join(f"{n} {v:.2f} s x{calls[n]}" for n, v in spent.items())
        over = " OVER BUDGET" if wall > args.budget else ""
        print(f"plan call {wall:.2f} s{over}: {r.status.name}, {r.iterations} it; {stages}")
        return r

    solve_module.plan_problem = traced
    run = secure3d.simulate(
        scenario, "secure", seed=args.seed + args.variant, plan_budget=args.budget
    )
    print(f"{scenario.name}: {run.outcome}; plan calls {[round(x, 2) for x in run.solve_times]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
