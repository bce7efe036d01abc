"""What the tracking guard costs, and whether it changes outcomes: each scenario flown by the
secure planner with the guard on and off, interleaved in one process (ratios are robust to load).
Writes ``benchmarks/results/guard.md``::

    .venv/bin/python benchmarks/bench_guard.py [--reps 2] [--maps blind_corner forest ...]
"""

from __future__ import annotations

import argparse
import statistics

from _common import REPO, atomic_write_text, machine_info, markdown_table

import secure3d
from secure3d.simulation import guard as guard_module
from secure3d.simulation.closed_loop import simulate

DEFAULT_MAPS = (
    "blind_corner",
    "blind_corner_quadrotor",
    "forest",
    "warehouse",
    "planar_blind_corner",
)


def _fly(name: str, guarded: bool) -> tuple[object, dict]:
    made: list = []
    original = guard_module.TrackingGuard.__init__

    def remember(self, *args, **kwargs):  # count the guard's quick and exact checks
        original(self, *args, **kwargs)
        made.append(self)

    guard_module.TrackingGuard.__init__ = remember
    try:
        run = simulate(secure3d.load_scenario(name), "secure", tracking_guard=guarded)
    finally:
        guard_module.TrackingGuard.__init__ = original
    counts = {"quick": made[0].quick, "exact": len(made[0].checks)} if made else {}
    return run, counts


def _machine_line() -> str:
    info = machine_info()
    return ", ".join(f"{k}: {v}" for k, v in info.items())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--reps", type=int, default=2)
    parser.add_argument("--maps", nargs="+", default=list(DEFAULT_MAPS))
    args = parser.parse_args()
    rows = []
    for name in args.maps:
        _fly(name, True)  # warm: NLP compiled, kernels loaded
        flights = {True: [], False: []}
        for _ in range(args.reps):
            for guarded in (True, False):
                flights[guarded].append(_fly(name, guarded))
        on, off = flights[True][-1][0], flights[False][-1][0]
        t_on = statistics.median(r.flight_time for r, _ in flights[True])
        t_off = statistics.median(r.flight_time for r, _ in flights[False])
        counts = flights[True][-1][1]
        trips = sum("tracking guard" in e.detail for e in on.events)
        rows.append(
            [
                name,
                f"{on.outcome} / {off.outcome}",
                f"{on.sim_time:.2f} / {off.sim_time:.2f} s",
                f"{t_on:.2f} / {t_off:.2f} s",
                f"{t_on / max(t_off, 1e-9):.2f}x",
                f"{counts.get('quick', 0)} / {counts.get('exact', 0)}",
                str(trips),
            ]
        )
        print(rows[-1], flush=True)
    header = [
        "scenario",
        "outcome on / off",
        "sim time on / off",
        "flight wall on / off",
        "cost",
        "quick / exact checks",
        "guard take-overs",
    ]
    text = (
        "# Tracking guard: cost and outcomes\n\n"
        f"`benchmarks/bench_guard.py --reps {args.reps}`, medians, guard on and off interleaved in"
        f" one process.\n\n{_machine_line()}\n\n" + markdown_table(header, rows) + "\n"
    )
    atomic_write_text(REPO / "benchmarks" / "results" / "guard.md", text)


if __name__ == "__main__":
    main()
