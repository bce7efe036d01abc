"""Voxel store: the log-odds updates of whole closed-loop flights, replayed (issues 17, 18).

Each scenario is flown once (secure planner, seed 0) while every update of the robot's map is
recorded: ``VoxelTable.add_logodds`` calls (codes, delta, clamps) and ``add_logodds_tiles`` calls
(a scan's free voxels as 4 x 4 x 4 tiles; a store without that method replays their codes through
``add_logodds``, converted before the timing). The recorded stream is then replayed into
a fresh table ``--reps`` times, timing the updates, one sorted listing (``items``) and a lookup of
every third voxel (``get``); the table's memory is reported. With ``--compare-with DIR`` (another
checkout, e.g. a ``git worktree`` at an older commit) the same stream is replayed into that
checkout's ``secure3d/mapping/store.py`` too, alternating with this one, and the final values of
both tables are checked to be equal bit for bit.

    .venv/bin/python benchmarks/bench_map_store.py --scenarios forest narrow_passage_20cm \
        --compare-with /work/before --out benchmarks/results/map_store.md
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import time
from pathlib import Path
from types import ModuleType

import numpy as np
from _common import REPO, atomic_write_text, fmt, machine_info, markdown_table

from secure3d.mapping import store
from secure3d.mapping.morton import tiles_to_codes
from secure3d.planning import NLPCache


def record_stream(scenario: str) -> tuple[list[tuple], str]:
    """Fly ``scenario`` and return its map's update calls and the flight's outcome: each call is
    ``(codes, delta, clamp_min, clamp_max)`` (``add_logodds``) or ``((blocks, masks), delta, ...)``
    (``add_logodds_tiles``, a scan's free voxels as 4 x 4 x 4 tiles)."""
    import secure3d

    calls: list[tuple] = []
    by_codes, by_tiles = store.VoxelTable.add_logodds, store.VoxelTable.add_logodds_tiles

    def spy_codes(table: store.VoxelTable, codes: np.ndarray, *args: float) -> None:
        calls.append((np.array(codes, np.int64), *args))
        by_codes(table, codes, *args)

    def spy_tiles(
        table: store.VoxelTable, blocks: np.ndarray, masks: np.ndarray, *a: float
    ) -> None:
        calls.append(((np.array(blocks, np.int64), np.array(masks, np.uint64)), *a))
        by_tiles(table, blocks, masks, *a)

    store.VoxelTable.add_logodds, store.VoxelTable.add_logodds_tiles = spy_codes, spy_tiles
    try:
        result = secure3d.simulate(
            REPO / "maps" / f"{scenario}.yaml", "secure", seed=0, cache=NLPCache()
        )
    finally:
        store.VoxelTable.add_logodds, store.VoxelTable.add_logodds_tiles = by_codes, by_tiles
    return calls, result.outcome


def as_codes(calls: list[tuple]) -> list[tuple]:
    """The same calls with every tile update listed as codes (for a store without tiles)."""
    return [((tiles_to_codes(*c[0]),) + c[1:]) if isinstance(c[0], tuple) else c for c in calls]


def load_store(checkout: Path) -> ModuleType:
    """``secure3d/mapping/store.py`` of another checkout, as a module of its own."""
    path = checkout / "secure3d" / "mapping" / "store.py"
    if not path.is_file():
        raise SystemExit(f"--compare-with: no {path}")
    spec = importlib.util.spec_from_file_location("other_store", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def table_bytes(table: object) -> int:
    """Bytes of the table's arrays (whatever its layout)."""
    return sum(v.nbytes for v in vars(table).values() if isinstance(v, np.ndarray))


def replay(module: ModuleType, calls: list[tuple]) -> tuple[dict, tuple]:
    """One replay into a fresh table: times (s), memory (bytes), and its final items."""
    table = module.VoxelTable()
    t0 = time.perf_counter()
    for what, *args in calls:
        if isinstance(what, tuple):
            table.add_logodds_tiles(*what, *args)
        else:
            table.add_logodds(what, *args)
    update = time.perf_counter() - t0
    t0 = time.perf_counter()
    items = table.items()
    listing = time.perf_counter() - t0
    t0 = time.perf_counter()
    table.get(items[0][::3])
    lookup = time.perf_counter() - t0
    times = {"update": update, "items": listing, "get": lookup, "bytes": table_bytes(table)}
    return times, items


def measure(scenario: str, modules: dict[str, ModuleType], reps: int) -> dict:
    recorded, outcome = record_stream(scenario)
    listed = as_codes(recorded)
    # each store replays what it takes: tiles where it has add_logodds_tiles, else their codes
    streams = {
        name: recorded if hasattr(m.VoxelTable, "add_logodds_tiles") else listed
        for name, m in modules.items()
    }
    codes = sum(len(c[0]) for c in listed)
    for m in modules.values():  # compile outside the timing
        m.VoxelTable().add_logodds(listed[0][0][:4].copy(), *listed[0][1:])
    replay(modules["this"], recorded[:3])
    runs: dict[str, list[dict]] = {name: [] for name in modules}
    finals = {}
    for _ in range(reps):
        for name, m in modules.items():
            times, finals[name] = replay(m, streams[name])
            runs[name].append(times)
    same = None
    if len(finals) == 2:
        (c1, v1), (c2, v2) = finals.values()
        same = bool(np.array_equal(c1, c2) and np.array_equal(v1, v2))
    return {
        "scenario": scenario,
        "outcome": outcome,
        "calls": len(recorded),
        "tile calls": sum(isinstance(c[0], tuple) for c in recorded),
        "codes": codes,
        "voxels": len(next(iter(finals.values()))[0]),
        "runs": runs,
        "same": same,
    }


def report(rows: list[dict], reps: int) -> str:
    names = list(rows[0]["runs"])
    head = ["scenario", "updates (calls, of which tiles / voxels)", "voxels at the end"]
    for n in names:
        head += [f"{n}: update (s)", f"{n}: items (s)", f"{n}: get (s)", f"{n}: MB"]
    if len(names) == 2:
        head += ["update ratio (this / other)", "same values"]
    body = []
    for r in rows:
        calls = f"{r['calls']}, {r['tile calls']} / {r['codes'] / 1e6:.1f} M"
        cells = [r["scenario"], calls, f"{r['voxels']:,}"]
        med = {
            n: {k: statistics.median(t[k] for t in r["runs"][n]) for k in r["runs"][n][0]}
            for n in names
        }
        for n in names:
            m = med[n]
            cells += [fmt(m["update"]), fmt(m["items"]), fmt(m["get"], 3), fmt(m["bytes"] / 1e6, 0)]
        if len(names) == 2:
            cells += [fmt(med["this"]["update"] / med["other"]["update"]), str(r["same"])]
        body.append(cells)
    info = machine_info()
    return "\n".join(
        [
            "# Voxel store: the log-odds updates of whole flights, replayed",
            "",
            f"`{' '.join(sys.argv)}`",
            "",
            f"Machine: {info}. Medians of {reps} replays, the checkouts alternating.",
            "",
            markdown_table(head, body),
            "",
        ]
    )


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenarios", nargs="+", default=["forest", "narrow_passage_20cm"])
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--compare-with", type=Path, help="another checkout to replay into as well")
    p.add_argument("--out", type=Path, help="write the markdown report here")
    args = p.parse_args(argv)
    modules = {"this": store}
    if args.compare_with is not None:
        modules["other"] = load_store(args.compare_with)
    rows = []
    for name in args.scenarios:
        print(f"{name}: flying and recording ...", file=sys.stderr, flush=True)
        rows.append(measure(name, modules, args.reps))
    text = report(rows, args.reps)
    print(text)
    if args.out is not None:
        atomic_write_text(args.out, text)


if __name__ == "__main__":
    main()
