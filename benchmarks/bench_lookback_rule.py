"""Cold plans with two first choices of look-back views, side by side (issue 18).

The adaptive rule ties each node to an earlier camera: first its best view (the largest margin on
the guess), and if that solve fails, the latest view with at least
``lookback.NEAR_VIEW_FRACTION`` of that margin. Here ``--fractions 1.0 0.9`` compares the default
(1.0: best views first) with the near views (fraction 0.9) as the first choice. Every scenario of
``maps/`` gets one cold secure ``plan()`` per choice (the server's map as belief, a fresh NLP cache
each), alternating per scenario in one process: status, final time, IPOPT iterations, wall time
and the certificate.

Run::

    .venv/bin/python benchmarks/bench_lookback_rule.py --fractions 1.0 0.9 \\
        --out benchmarks/results/lookback_rule.md
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from _common import REPO, atomic_write_text, fmt, machine_info, markdown_table, timed

import secure3d
from secure3d.planning import NLPCache
from secure3d.planning import lookback as lb

_ADAPTIVE = lb.adaptive_assignment


def cold_plan(scenario: Path, fraction: float) -> dict:
    """One cold secure plan of ``scenario`` whose first views are the near ones of ``fraction``
    (1.0: the best views, the default)."""
    first = None if fraction >= 1.0 else fraction

    def views(problem, states, near_fraction=None):  # noqa: ANN001, ANN202 - a stand-in
        return _ADAPTIVE(problem, states, first if near_fraction is None else near_fraction)

    lb.adaptive_assignment = views
    try:
        run = timed(lambda: secure3d.plan(str(scenario), "secure", cache=NLPCache()))
    finally:
        lb.adaptive_assignment = _ADAPTIVE
    if run.error is not None:
        return {"status": f"error: {run.error}", "wall": run.wall}
    r = run.value
    return {
        "status": r.status.value,
        "T": float(r.final_time),
        "iterations": int(r.iterations),
        "wall": run.wall,
        "certified": bool(r.certificate is not None and r.certificate.ok),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fractions", type=float, nargs=2, default=[1.0, 0.9])
    ap.add_argument("--only", nargs="*", help="scenario names (default: every maps/*.yaml)")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks/results/lookback_rule.md")
    args = ap.parse_args()
    if not all(0.0 < f <= 1.0 for f in args.fractions):
        ap.error(f"--fractions: two numbers in (0, 1], got {args.fractions}")
    scenarios = sorted((REPO / "maps").glob("*.yaml"))
    if args.only:
        scenarios = [s for s in scenarios if s.stem in args.only]
    secure3d.plan(str(REPO / "maps/blind_corner.yaml"), "secure")  # imports and kernels warm
    t0, load0 = time.perf_counter(), os.getloadavg()[0]
    results: dict = {}
    for k, sc in enumerate(scenarios):
        order = args.fractions if k % 2 == 0 else args.fractions[::-1]
        results[sc.stem] = {str(f): cold_plan(sc, f) for f in order}
        print(sc.stem, json.dumps(results[sc.stem]), file=sys.stderr, flush=True)
    a, b = (str(f) for f in args.fractions)
    head = ["scenario", f"status {a} / {b}", f"T {a} (s)", f"T {b} (s)", f"iterations {a}"]
    head += [f"iterations {b}", f"wall {a} (s)", f"wall {b} (s)", "certified"]
    rows = []
    for name, r in results.items():
        x, y = r[a], r[b]
        rows.append(
            [name, f"{x['status']} / {y['status']}", fmt(x.get("T")), fmt(y.get("T"))]
            + [str(x.get("iterations", "")), str(y.get("iterations", ""))]
            + [fmt(x["wall"]), fmt(y["wall"]), f"{x.get('certified')} / {y.get('certified')}"]
        )
    sums = {f: sum(r[f]["wall"] for r in results.values()) for f in (a, b)}
    text = [
        "# Cold plans with two first choices of look-back views",
        "",
        "Command: `.venv/bin/python benchmarks/bench_lookback_rule.py "
        + " ".join(sys.argv[1:])
        + "`",
        "",
        f"Machine: `{json.dumps(machine_info())}`; load (1-min average) {load0:.2f} at the start,"
        f" {os.getloadavg()[0]:.2f} at the end; {time.perf_counter() - t0:.0f} s in all.",
        "",
        f"First views of fraction {a} against {b} (1.0: the best views, the default); wall time of"
        f" all plans: {sums[a]:.1f} s against {sums[b]:.1f} s.",
        "",
        markdown_table(head, rows),
        "",
    ]
    atomic_write_text(args.out, "\n".join(text))
    print(args.out)


if __name__ == "__main__":
    main()
