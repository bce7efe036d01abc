"""How often does the certificate reject the solver's first success? (issue 16, item 4)

Flies variants of scenario families in closed loop with the secure planner and counts, over every
plan call whose solver succeeded, how many solutions the certificate rejected before one certified
(``SimResult.certify_log``), with the first rejection's reason.

    python benchmarks/bench_certificate_rate.py --cases blind_corner:corner,blind_corner:thin -n 10
"""

from __future__ import annotations

import argparse
import collections
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import atomic_write_text  # noqa: E402

from secure3d.simulation.campaign_run import _family  # noqa: E402
from secure3d.simulation.closed_loop import simulate  # noqa: E402
from secure3d.world.families import family_variants  # noqa: E402
from secure3d.world.scenario import load_scenario  # noqa: E402


def _variants(case: str, n: int, seed: int) -> list:
    """``base`` alone, or ``base:family`` variants 0..n-1."""
    base_name, _, kind = case.partition(":")
    base = load_scenario(base_name)
    if not kind:
        return [base]
    return family_variants(_family(kind, 1), base, n, seed)


def _reason(event_detail: str) -> str:
    """The kind of the first rejected violation, from the flight's certificate event."""
    m = re.search(r"m\]: (.*) \(margin", event_detail)
    return m.group(1) if m else event_detail


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="blind_corner:corner,blind_corner:thin,beam_3d:occlusion3d")
    ap.add_argument("-n", type=int, default=10, help="variants per family case")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--nodes", type=int, default=30)
    ap.add_argument("--time-limit", type=float, default=30.0)
    ap.add_argument("--out", default="benchmarks/results/certificate_rate.md")
    args = ap.parse_args(argv)
    rows, reasons = [], collections.Counter()
    for case in args.cases.split(","):
        calls = first = certified = runs = 0
        t0 = time.perf_counter()
        for i, sc in enumerate(_variants(case, args.n, args.seed)):
            r = simulate(
                sc, "secure", seed=args.seed + i, nodes=args.nodes, time_limit=args.time_limit
            )
            runs += 1
            calls += len(r.certify_log)
            first += sum(1 for k, ok in r.certify_log if k == 0 and ok)
            certified += sum(1 for _, ok in r.certify_log if ok)
            for e in r.events:
                if e.kind == "certificate":
                    reasons[(case, _reason(e.detail))] += 1
            print(f"{case} #{i}: {r.outcome}, judged calls {r.certify_log}", file=sys.stderr)
        rate = first / calls if calls else float("nan")
        rows.append((case, runs, calls, first, certified, rate, time.perf_counter() - t0))
    lines = [
        "| case | runs | judged plan calls | certified first try | certified in the end | first-try rate | wall (s) |",
        "|---|---:|---:|---:|---:|---:|---:|",
        *(
            f"| {c} | {n} | {k} | {f} | {ce} | {100 * r:.1f} % | {w:.0f} |"
            for c, n, k, f, ce, r, w in rows
        ),
        "",
        "| case | first rejection's reason | count |",
        "|---|---|---:|",
        *(f"| {c} | {why} | {k} |" for (c, why), k in reasons.most_common()),
    ]
    text = "\n".join(lines)
    print(text)
    atomic_write_text(
        args.out, f"# Certificate first-try rate\n\n`{' '.join(sys.argv)}`\n\n{text}\n"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
