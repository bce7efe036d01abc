"""Plans and closed-loop outcomes with 1 and 2 OpenBLAS threads, on every scenario in maps/.

Each (scenario, thread count) runs in a new process with ``OPENBLAS_NUM_THREADS`` set, as a user's
environment would; the planner pins CasADi's OpenBLAS itself (``secure3d/planning/blas.py``), so
every row should agree bit for bit. Writes ``benchmarks/results/blas_threads.md``::

    .venv/bin/python benchmarks/bench_blas_threads.py [--closed-loop] [--maps a.yaml b.yaml]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from _common import REPO, atomic_write_text, machine_info, markdown_table

_CHILD = """
import json, sys, secure3d
from secure3d.world.scenario import load_scenario
s = load_scenario(sys.argv[1])
out = {}
for p in ("secure", "baseline"):
    r = secure3d.plan(s, p)
    out[p] = [r.status.name, r.final_time, r.solve_time]
if sys.argv[2] == "1":
    sim = secure3d.simulate(s, "secure")
    out["closed_loop"] = [sim.collided, sim.reached_goal, sim.time_to_goal, sim.replans]
print("RESULT " + json.dumps(out))
"""


def run(path: Path, threads: int, closed_loop: bool) -> dict:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": str(threads), "PYTHONPATH": str(REPO)}
    env.pop("SECURE3D_BLAS_THREADS", None)
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, str(path), "1" if closed_loop else "0"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=1800,
    )
    for line in out.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    return {
        "error": out.stderr.strip().splitlines()[-1][:200] if out.stderr.strip() else "no result"
    }


def _cell(res: dict, key: str) -> str:
    if "error" in res:
        return res["error"]
    status, T, _ = res[key]
    return f"{status} T={T!r}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--closed-loop", action="store_true", help="also fly each scenario (secure)")
    ap.add_argument("--maps", nargs="*", help="scenario files (default: maps/*.yaml)")
    ap.add_argument("--out", default=str(REPO / "benchmarks/results/blas_threads.md"))
    args = ap.parse_args(argv)
    paths = [Path(p) for p in args.maps] if args.maps else sorted((REPO / "maps").glob("*.yaml"))
    rows, same_all = [], True
    for path in paths:
        one, two = run(path, 1, args.closed_loop), run(path, 2, args.closed_loop)
        same = (
            "error" not in one
            and "error" not in two
            and all(one[k][:2] == two[k][:2] for k in ("secure", "baseline"))
            and one.get("closed_loop") == two.get("closed_loop")
        )
        same_all &= bool(same)
        row = [
            path.stem,
            _cell(one, "secure"),
            _cell(two, "secure"),
            _cell(one, "baseline"),
            _cell(two, "baseline"),
        ]
        if args.closed_loop:
            row += [str(one.get("closed_loop")), str(two.get("closed_loop"))]
        rows.append(row + ["yes" if same else "**no**"])
        print(" | ".join(rows[-1]), flush=True)
    header = ["scenario", "secure, 1 thread", "secure, 2 threads", "baseline, 1", "baseline, 2"]
    if args.closed_loop:
        header += ["closed loop 1 (collided, goal, t, replans)", "closed loop 2"]
    header += ["identical"]
    text = (
        "# Plans with 1 and 2 OpenBLAS threads\n\n"
        f"`benchmarks/bench_blas_threads.py{' --closed-loop' if args.closed_loop else ''}`, "
        f"machine: {json.dumps(machine_info())}\n\n"
        "Status and final time T of `secure3d.plan` (and the secure closed-loop outcome), each in a "
        "new process with `OPENBLAS_NUM_THREADS` = 1 or 2. Identical means status, T (bit for bit) "
        "and closed-loop outcome agree.\n\n" + markdown_table(header, rows) + "\n"
    )
    atomic_write_text(args.out, text)
    print(f"all identical: {same_all} -> {args.out}")
    return 0 if same_all else 1


if __name__ == "__main__":
    sys.exit(main())
