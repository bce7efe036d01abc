"""A new install's first flight of each shipped vehicle, with and without ``make warm``'s node
kernels (the NLP's derivative Functions compiled to C, :mod:`secure3d.planning.compiled_kernels`).

The node kernels are compiled per model, limits and reactive-set family. A first flight whose
kernels have no library runs them in CasADi's virtual machine (and, in the default ``auto`` mode,
compiles nothing for a kernel no earlier process met). Each case is a new Python process with its
own kernel cache (``SECURE3D_KERNEL_CACHE_DIR``, a new temporary folder; numba's cache is the
user's, as after ``make venv``):

- *empty*: nothing compiled (a new empty folder for every such flight);
- *warm*: after :func:`secure3d.warm.warm` into that folder (timed, in its own process).

Reported per flight: outcome, simulated time, flight wall time, its plan calls, and the real-time
factor. Run::

    .venv/bin/python benchmarks/bench_warm_vehicles.py [--out results/warm_vehicles.md]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _common import REPO, atomic_write_text, machine_info, markdown_table, python_json

FLIGHTS = ("blind_corner_quadrotor", "forest", "planar_blind_corner")

_FLY = r"""
import json, sys
import secure3d
from secure3d.planning.collocation import NLPCache
run = secure3d.simulate(sys.argv[1], "secure", seed=0, cache=NLPCache())
print(json.dumps({"outcome": run.outcome, "sim": run.sim_time, "flight": run.flight_time,
                  "plans": float(sum(run.solve_times))}))
"""
_WARM = "from secure3d.warm import warm; warm()"


def _warm(env: dict) -> float:
    """Seconds :func:`secure3d.warm.warm` takes in a new process with ``env``."""
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", _WARM], cwd=REPO, env=env, capture_output=True, text=True
    )
    if done.returncode:
        raise SystemExit(f"warm() failed:\n{done.stderr[-3000:]}")
    return time.perf_counter() - t0


def fly(name: str, env: dict) -> dict:
    row = python_json(_FLY, [str(REPO / "maps" / f"{name}.yaml")], REPO, env)
    if "error" in row:
        raise SystemExit(f"{name}: {row['error']}")
    row["rtf"] = row["sim"] / row["flight"]
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", nargs="+", default=list(FLIGHTS))
    ap.add_argument("--out", type=Path, help="markdown file (default: print only)")
    args = ap.parse_args()
    rows, warm_seconds = [], None
    base = {k: v for k, v in os.environ.items() if k != "SECURE3D_KERNEL_COMPILE"}
    with tempfile.TemporaryDirectory() as warmed:
        warm_seconds = _warm({**base, "SECURE3D_KERNEL_CACHE_DIR": warmed})
        for name in args.flights:  # alternating, each in a new process
            for case in ("empty", "warm"):
                # a new empty folder for each such flight: in an emptied one a second process
                # would compile the kernels an earlier one marked as seen
                with tempfile.TemporaryDirectory() as empty:
                    folder = empty if case == "empty" else warmed
                    r = fly(name, {**base, "SECURE3D_KERNEL_CACHE_DIR": folder})
                cells = [r["outcome"], f"{r['sim']:.2f}", f"{r['flight']:.2f}", f"{r['plans']:.2f}"]
                rows.append([name, case, *cells, f"{r['rtf']:.2f}x"])
                print(*rows[-1], flush=True)
    table = markdown_table(
        [
            "flight",
            "kernel cache",
            "outcome",
            "sim (s)",
            "flight wall (s)",
            "plan calls (s)",
            "RTF",
        ],
        rows,
    )
    text = (
        "# First flight of each vehicle, with and without `make warm`'s node kernels\n\n"
        f"Command: `python benchmarks/bench_warm_vehicles.py {' '.join(sys.argv[1:])}`\n\n"
        f"Machine: `{json.dumps(machine_info())}`\n\n"
        f"`warm()` into an empty kernel cache: {warm_seconds:.1f} s (its own process).\n\n"
        f"{table}\n"
    )
    print(text)
    if args.out:
        atomic_write_text(
            args.out if args.out.is_absolute() else REPO / "benchmarks" / args.out, text
        )


if __name__ == "__main__":
    main()
