"""The first plan of a new process: with numba's kernels compiled from nothing, loaded from the
user's cache, and in a fresh clone of the repository (issue 17, item 3).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_first_run.py

Each case is a new Python process that imports secure3d, loads ``maps/blind_corner.yaml`` and times
one secure ``plan()`` (cold NLP cache), then a second one in the same process (everything warm):

- *empty cache*: ``SECURE3D_NUMBA_CACHE_DIR`` an empty folder (every kernel compiles);
- *warm cache*: the user's cache after ``make warm`` (this checkout);
- *fresh clone*: ``git clone`` of this checkout into a temporary folder (new paths, new file
  times), run from there with the same user cache: the kernels are found by their sources' digest.

Writes ``benchmarks/results/first_run.md``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_CHILD = r"""
import json, sys, time
t0 = time.perf_counter()
from secure3d.planning import NLPCache
from secure3d.planning.solve import plan
from secure3d.world import load_scenario
import secure3d
s = load_scenario(sys.argv[1])
t1 = time.perf_counter()
first = plan(s, "secure", cache=NLPCache())
t2 = time.perf_counter()
second = plan(s, "secure", cache=NLPCache())
t3 = time.perf_counter()
print(json.dumps({"package": secure3d.__file__, "imports": t1 - t0, "first": t2 - t1,
                  "second": t3 - t2, "ok": bool(first.ok and second.ok)}))
"""


def run(checkout: Path, env: dict) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", _CHILD, str(checkout / "maps" / "blind_corner.yaml")],
        cwd=checkout,
        env={**env, "PYTHONPATH": str(checkout)},
        capture_output=True,
        text=True,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    env = dict(os.environ)
    env.pop("NUMBA_CACHE_DIR", None)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-c", "from secure3d.warm import warm; warm()"],
            cwd=ROOT,
            env={**env, "PYTHONPATH": str(ROOT)},
            check=True,
            capture_output=True,
        )
        rows.append(("warm cache (this checkout)", run(ROOT, env)))
        clone = Path(tmp) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        rows.append(("fresh clone, same user cache", run(clone, env)))
        empty = {**env, "SECURE3D_NUMBA_CACHE_DIR": str(Path(tmp) / "empty")}
        rows.append(("empty cache (compiles every kernel)", run(ROOT, empty)))
        rows.append(("warm cache again", run(ROOT, env)))
    load = os.getloadavg()
    md = [
        "# First plan of a new process (issue 17, item 3)",
        "",
        "blind_corner, one secure `plan()` with a cold NLP cache in a new process, then a second in"
        " the same process. The bar: the first plan at most 2x a warm process's.",
        "",
        "| case | imports (s) | first plan (s) | second plan (s) | first / second | ok |",
        "|---|---|---|---|---|---|",
    ]
    for label, r in rows:
        md.append(
            f"| {label} | {r['imports']:.2f} | {r['first']:.2f} | {r['second']:.2f} |"
            f" {r['first'] / r['second']:.1f} | {r['ok']} |"
        )
    md += ["", f"Load average at the end: {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} (2 cores)."]
    out = ROOT / "benchmarks" / "results" / "first_run.md"
    out.write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
