"""Closed-loop NLP time per IPOPT iteration against ``plan()``'s on the same scene (issue 18, item 1).

For each scenario, in one process and alternating, ``--reps`` times:

- a secure closed-loop flight (``secure3d.simulate``, seed 0, a new NLP cache) with the look-back
  encoding ``--encoding`` (the closed loop's default unless given): every IPOPT solve of its plan
  calls is recorded with IPOPT's own statistics (iterations; wall time in the NLP functions, of
  which the Lagrangian Hessian and the constraint Jacobian; the rest is IPOPT's linear algebra,
  mostly the MUMPS factorisation);
- a cold ``plan()`` of the scenario with the planner's defaults (8 obstacle slots), and one with the
  closed loop's options (12 slots).

Reported: ms per iteration (solve wall time / iterations, summed over the solves), the split, the
closed loop's NLP builds and plan-call time, and the ratio closed loop / ``plan()``. Ratios are
measured side by side in one process, so machine load cancels to first order (the load average is
in the header). Run::

    .venv/bin/python benchmarks/bench_nlp_iteration.py [--scenarios forest ...] [--encoding parameter]
        [--reps 2] [--out results/nlp_iteration.md]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from _common import REPO, atomic_write_text, machine_info, markdown_table

SCENARIOS = ("forest", "blind_corner_quadrotor", "blind_corner")
TARGET_RATIO = 1.5


class SolveLog:
    """Every IPOPT solve's iterations, wall time and NLP-function time (IPOPT's statistics)."""

    def __init__(self) -> None:
        from secure3d.planning import nlp_solve

        self.rows: list[dict] = []
        self._module, self._read = nlp_solve, nlp_solve._read_solution

        def read(run, sol, stats, solve_time):  # noqa: ANN001, ANN202 (mirrors _read_solution)
            nlp = run.nlp
            self.rows.append(
                {
                    "it": int(stats.get("iter_count", 0)),
                    "wall": float(solve_time),
                    "hess": float(stats.get("t_wall_nlp_hess_l", 0.0)),
                    "jac": float(stats.get("t_wall_nlp_jac_g", 0.0)),
                    "eval": sum(float(v) for k, v in stats.items() if k.startswith("t_wall_nlp")),
                    "n_w": int(nlp.layout.n_w),
                }
            )
            return self._read(run, sol, stats, solve_time)

        nlp_solve._read_solution = read

    def take(self) -> list[dict]:
        rows, self.rows = self.rows, []
        return rows


def per_iteration(rows: list[dict]) -> dict:
    it = max(sum(r["it"] for r in rows), 1)
    total = {k: sum(r[k] for r in rows) for k in ("wall", "hess", "jac", "eval")}
    return {
        "solves": len(rows),
        "iterations": sum(r["it"] for r in rows),
        "ms_it": 1e3 * total["wall"] / it,
        "eval_ms_it": 1e3 * total["eval"] / it,
        "hess_ms_it": 1e3 * total["hess"] / it,
        "linalg_ms_it": 1e3 * (total["wall"] - total["eval"]) / it,
        "n_w": max((r["n_w"] for r in rows), default=0),
    }


def closed_loop(log: SolveLog, path: Path, encoding: str | None) -> dict:
    import secure3d
    from secure3d.planning.nlp_cache import NLPCache

    opts = {} if encoding is None else {"lookback_encoding": encoding}
    log.take()
    run = secure3d.simulate(path, "secure", seed=0, cache=NLPCache(), **opts)
    out = per_iteration(log.take())
    out.update(
        outcome=run.outcome,
        sim=float(run.sim_time),
        flight=float(run.flight_time),
        plan_calls=len(run.solve_times),
        plan_wall=float(sum(run.solve_times)),
        builds=float(sum(p.build_time for _, p in run.plans)),
    )
    return out


def cold_plan(log: SolveLog, path: Path, **options: object) -> dict:
    import secure3d
    from secure3d.planning.nlp_cache import NLPCache

    log.take()
    t0 = time.perf_counter()
    result = secure3d.plan(path, "secure", cache=NLPCache(), **options)
    out = per_iteration(log.take())
    out.update(status=result.status.value, call=time.perf_counter() - t0, build=result.build_time)
    return out


def _machine() -> str:
    m = machine_info()
    return f"Commit {m['commit']}{' (dirty)' if m['dirty'] else ''}, {m['date']}, {m['cpus']} CPUs, casadi {m['casadi']}"


def median(rows: list[dict], key: str) -> float:
    return float(np.median([r[key] for r in rows]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    ap.add_argument("--encoding", choices=("structure", "parameter"), default=None)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    log = SolveLog()
    load = os.getloadavg()[0]
    table = []
    for name in args.scenarios:
        path = REPO / "maps" / f"{name}.yaml"
        cl, p8, p12 = [], [], []
        for _ in range(args.reps):
            cl.append(closed_loop(log, path, args.encoding))
            p8.append(cold_plan(log, path))
            p12.append(cold_plan(log, path, obstacle_slots=12))
        ms = median(cl, "ms_it")
        table.append(
            [
                name,
                cl[0]["outcome"],
                f"{cl[0]['iterations']} in {cl[0]['solves']}",
                f"{ms:.1f}",
                f"{median(cl, 'hess_ms_it'):.1f} / {median(cl, 'eval_ms_it'):.1f}",
                f"{median(cl, 'linalg_ms_it'):.1f}",
                f"{median(cl, 'builds'):.2f}",
                f"{median(cl, 'plan_wall'):.2f} ({cl[0]['plan_calls']})",
                f"{median(cl, 'flight'):.2f} / {cl[0]['sim']:.2f}",
                f"{median(p8, 'ms_it'):.1f}",
                f"{median(p12, 'ms_it'):.1f}",
                f"{ms / median(p8, 'ms_it'):.2f}x / {ms / median(p12, 'ms_it'):.2f}x",
            ]
        )
        print(" | ".join(table[-1]), flush=True)
    header = [
        "scenario",
        "outcome",
        "iterations in solves",
        "closed loop ms/it",
        "of which Hessian / all NLP functions",
        "IPOPT linear algebra ms/it",
        "NLP builds in flight (s)",
        "plan calls (s) (n)",
        "flight / simulated (s)",
        "plan() ms/it (8 slots)",
        "plan() ms/it (12 slots)",
        "ratio (8 / 12 slots)",
    ]
    enc = args.encoding or "the closed loop's default"
    text = (
        f"# Closed-loop NLP time per IPOPT iteration vs plan()\n\n{_machine()}; load average "
        f"{load:.2f} at the start. Look-back encoding in closed loop: {enc}. Medians of "
        f"{args.reps}, alternating in one process.\n\n"
        + markdown_table(header, table)
        + f"\n\nTarget (issue 18): closed-loop time per iteration at most {TARGET_RATIO}x plan()'s.\n"
    )
    print(text)
    if args.out:
        atomic_write_text(args.out, text)


if __name__ == "__main__":
    main()
