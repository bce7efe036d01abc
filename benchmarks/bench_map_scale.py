"""Load time and memory of server maps of 10^4, 10^5 and 10^6 occupied voxels (issue 24, item 4).

    PYTHONPATH=. .venv/bin/python benchmarks/bench_map_scale.py [--plan]

Maps (written to a temporary folder as ``.bt``):

- *real*: ``maps/octomaps/geb079.bt`` (185,673 occupied voxels at 0.08 m) cropped to about 10^4
  and 10^5 occupied voxels, and refined to 0.04 m (every voxel split in 8: 1.49 M) for 10^6;
- *synthetic*: a room-like world of vertical walls on a random grid at 0.05 m, grown until it
  has about 10^4, 10^5, 10^6 occupied voxels (each wall 1-4 m long, 0.1 m thick, 2.5 m high).

Each load runs in a fresh Python process (imports and numba caches warmed first) and reports the
wall time of ``OccupancyMap.read_bt`` and of taking it as the claim of a belief map
(``set_claim_from_map``, what ``belief_map`` does) the first time in the process (numba's cached
kernels are loaded then) and a second time, the resident memory before and after (``VmRSS``) and
the process's peak (``ru_maxrss``, imports included). ``--plan`` also times one secure ``plan()`` of
``maps/geb079_region_attacks.yaml`` (the real 185 k-voxel map) beside one of
``maps/blind_corner.yaml``, in one process, cold NLP cache each: the ratio is the issue-17 bar
(at most 3x), left to issue 17's spatial index. Writes ``benchmarks/results/map_scale.md``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGETS = (10_000, 100_000, 1_000_000)

ROUTES_NOTE = """Routes: the real maps fly geb079's corridor route (`geb079_region_attacks`, 3.45 s plans); the
synthetic ones a route as long as the blind corner's start-goal distance (8.7 m) through the middle
of the random walls, so that the maps differ in size and not in route length, and, as a second row,
the 57 m diagonal across them (15.1 s plans, 3.6x the blind corner's, with the same 40 nodes: its
cost grows with the walls along it, not with the map's size alone). Each ratio divides by a
blind-corner plan() timed just before (cold NLP cache too), so a change of load between rows does
not skew it. Bar (issues 17 and 24): at most 3x the blind corner's whole call at ~10^6 voxels."""

_CHILD = r"""
import json, resource, sys, time
import numpy as np
from secure3d.mapping import OccupancyMap

def rss_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024

rss0 = rss_mb()
t0 = time.perf_counter()
m = OccupancyMap.read_bt(sys.argv[1])
t1 = time.perf_counter()
belief = OccupancyMap(m.resolution)
belief.set_claim_from_map(m)
t2 = time.perf_counter()
n = len(belief.claimed_voxels(True))
rss1 = rss_mb()
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
t3 = time.perf_counter()
OccupancyMap(m.resolution).set_claim_from_map(OccupancyMap.read_bt(sys.argv[1]))
t4 = time.perf_counter()
print(json.dumps({"read": t1 - t0, "claim": t2 - t1, "warm": t4 - t3, "occupied": n,
                  "rss0_mb": rss0, "rss1_mb": rss1, "peak_mb": peak}))
"""


def _write(path: Path, codes: np.ndarray, res: float) -> None:
    from secure3d.mapping import octomap_io
    from secure3d.mapping.keys import TREE_DEPTH, unique_sorted

    codes = unique_sorted(codes)
    depths = np.full(codes.size, TREE_DEPTH, np.int8)
    vals = np.ones(codes.size, np.float32)
    s, d, v = octomap_io.prune(codes, depths, vals, stop_at_first_unpruned_level=True)
    path.write_bytes(octomap_io.write_bt_bytes(res, s, d, v > 0))


def real_maps(folder: Path) -> list[tuple[str, Path]]:
    from secure3d.mapping import OccupancyMap
    from secure3d.mapping.keys import coords_to_codes

    geb = OccupancyMap.read_bt(ROOT / "maps" / "octomaps" / "geb079.bt")
    occ = geb.occupied_voxels()
    out = []
    for target, name in ((10_000, "1e4"), (100_000, "1e5")):
        xmax = np.quantile(occ[:, 0], target / len(occ))
        crop = occ[occ[:, 0] <= xmax]
        p = folder / f"real_{name}.bt"
        _write(p, coords_to_codes(crop, 0.08)[0], 0.08)
        out.append((f"real {name}: geb079 cropped to x <= {xmax:.1f} m", p))
    offsets = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)]) * 0.02
    fine = (occ[:, None, :] + offsets[None]).reshape(-1, 3)
    p = folder / "real_1e6.bt"
    _write(p, coords_to_codes(fine, 0.04)[0], 0.04)
    out.append(("real 1e6: geb079 refined to 0.04 m", p))
    return out


def synthetic_maps(folder: Path) -> list[tuple[str, Path]]:
    from secure3d.mapping.keys import coords_to_codes

    res = 0.05
    rng = np.random.default_rng(0)
    out = []
    codes = np.empty(0, np.int64)
    for target, name in zip(TARGETS, ("1e4", "1e5", "1e6"), strict=True):
        while codes.size < target:
            a = rng.uniform(-40, 40, 2)
            length = rng.uniform(1, 4)
            axis = int(rng.integers(2))
            xs = np.arange(0, length, res)
            zs = np.arange(0, 2.5, res)
            ts = np.arange(0, 0.1, res)
            g = np.stack(np.meshgrid(xs, ts, zs, indexing="ij"), -1).reshape(-1, 3)
            if axis:
                g = g[:, [1, 0, 2]]
            pts = g + np.array([a[0], a[1], 0.0]) + 0.5 * res
            codes = np.unique(np.concatenate([codes, coords_to_codes(pts, res)[0]]))
        p = folder / f"synthetic_{name}.bt"
        _write(p, codes, res)
        out.append((f"synthetic {name}: random walls at 0.05 m", p))
    return out


def load_in_child(path: Path) -> dict:
    env_path = str(ROOT)
    # warm numba's cache once (compiled kernels are cached on disk)
    cmd = [sys.executable, "-c", _CHILD, str(path)]
    env = {"PYTHONPATH": env_path, "PATH": "/usr/bin:/bin"}
    res = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def plan_ratio() -> dict:
    from secure3d.planning import NLPCache
    from secure3d.planning.solve import plan
    from secure3d.world import load_scenario

    out = {}
    for name in ("blind_corner", "geb079_region_attacks"):
        s = load_scenario(ROOT / "maps" / f"{name}.yaml")
        t0 = time.perf_counter()
        r = plan(s, "secure", cache=NLPCache())
        out[name] = (time.perf_counter() - t0, r.ok)
    return out


def _free_point(occ: np.ndarray, res: float, near: np.ndarray, clear: float) -> np.ndarray:
    """The point nearest ``near`` on a 0.5 m grid at least ``clear`` m from every voxel centre."""
    from scipy.spatial import cKDTree

    tree = cKDTree(occ)
    for radius in np.arange(0.0, 10.0, 0.5):
        for dx in np.arange(-radius, radius + 1e-9, 0.5):
            for dy in np.arange(-radius, radius + 1e-9, 0.5):
                p = near + np.array([dx, dy, 0.0])
                if tree.query(p)[0] > clear + res:
                    return p
    raise RuntimeError("no free point")


def size_scenario(label: str, path: Path, diagonal: bool = False):
    """A scenario whose server map is ``path``: geb079's corridor route for the real maps; for the
    synthetic ones a route as long as the blind corner's (its start-goal distance) through the
    middle of the random walls, so that the maps differ in size and not in route length, or with
    ``diagonal`` the 57 m diagonal across them."""
    import dataclasses

    from secure3d.mapping import OccupancyMap
    from secure3d.world import load_scenario
    from secure3d.world.spec import Bounds

    if label.startswith("real"):
        s = load_scenario(ROOT / "maps" / "geb079_region_attacks.yaml")
        res = 0.04 if "1e6" in label else 0.08
        server = dataclasses.replace(s.server_map, bt=path, resolution=res)
        return dataclasses.replace(s, server_map=server)
    s = load_scenario(ROOT / "maps" / "blind_corner.yaml")
    occ = OccupancyMap.read_bt(path).occupied_voxels()
    if diagonal:
        a = _free_point(occ, 0.05, np.array([-20.0, -20.0, 1.25]), 1.2)
        b = _free_point(occ, 0.05, np.array([20.0, 20.0, 1.25]), 1.2)
    else:
        half = 0.5 * np.linalg.norm(np.subtract(s.goal.position, s.start.position)) / np.sqrt(2)
        a = _free_point(occ, 0.05, np.array([-half, -half, 1.25]), 1.2)
        b = _free_point(occ, 0.05, np.array([half, half, 1.25]), 1.2)
    world = dataclasses.replace(
        s.world, bounds=Bounds((-41.0, -41.0, 0.0), (41.0, 41.0, 2.6)), boxes=(), meshes=()
    )
    server = dataclasses.replace(s.server_map, attacks=(), bt=path, resolution=0.05)
    return dataclasses.replace(
        s,
        name=f"synthetic_{path.stem}",
        world=world,
        server_map=server,
        start=dataclasses.replace(s.start, position=tuple(a)),
        goal=dataclasses.replace(s.goal, position=tuple(b)),
    )


def plan_by_size(maps: list[tuple[str, Path]]) -> list[str]:
    """One secure plan() per map, cold NLP cache, against blind_corner's in the same process."""
    from secure3d.planning import NLPCache
    from secure3d.planning.solve import plan
    from secure3d.world import load_scenario

    def timed(s):
        t0 = time.perf_counter()
        r = plan(s, "secure", cache=NLPCache())
        return time.perf_counter() - t0, r

    corner = load_scenario(ROOT / "maps" / "blind_corner.yaml")
    plan(corner, "secure")  # numba, imports
    rows = [
        "| map | plan() (s) | status | final time (s) | blind_corner just before (s) | ratio |",
        "|---|---:|---|---:|---:|---:|",
    ]
    cases = [(label, path, False) for label, path in maps]
    cases += [(label, path, True) for label, path in maps if label.startswith("synthetic")]
    for label, path, diagonal in cases:
        scenario = size_scenario(label, path, diagonal)
        tb, _ = timed(corner)  # paired: the machine's load changes between maps
        t, r = timed(scenario)
        label += ", 57 m diagonal" if diagonal else ""
        rows.append(
            f"| {label} | {t:.2f} | {r.status.value} | {r.final_time:.2f} | {tb:.2f} |"
            f" {t / tb:.1f} |"
        )
        print(rows[-1], flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--plan", action="store_true")
    ap.add_argument("--plan-by-size", action="store_true", help="plan() over each map too")
    args = ap.parse_args()
    rows = [
        "| map | file (KB) | occupied voxels | read_bt (s) | claim (s) | first load (s) |"
        " second load (s) | RSS before / after (MB) | peak RSS (MB) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        maps = real_maps(folder) + synthetic_maps(folder)
        load_in_child(maps[0][1])  # warm numba's on-disk cache
        for label, path in maps:
            r = load_in_child(path)
            row = (
                f"| {label} | {path.stat().st_size // 1024} | {r['occupied']} | {r['read']:.3f} |"
                f" {r['claim']:.3f} | {r['read'] + r['claim']:.3f} | {r['warm']:.3f} |"
                f" {r['rss0_mb']:.0f} / {r['rss1_mb']:.0f} | {r['peak_mb']:.0f} |"
            )
            print(row, flush=True)
            rows.append(row)
        by_size = plan_by_size(maps) if args.plan_by_size else []
    text = "# Server-map load time and memory by size (issue 24, item 4)\n\n" + "\n".join(rows)
    if by_size:
        text += (
            "\n\nOne secure `plan()` with each map as the server's map (`--plan-by-size`), cold NLP"
        )
        text += " cache, in one process:\n\n" + "\n".join(by_size) + "\n\n" + ROUTES_NOTE
    if args.plan:
        pr = plan_ratio()
        (tb, okb), (tg, okg) = pr["blind_corner"], pr["geb079_region_attacks"]
        line = (
            f"\n\nOne secure plan(), cold cache, same process: blind_corner {tb:.1f} s (ok={okb}),"
            f" geb079_region_attacks {tg:.1f} s (ok={okg}): ratio {tg / tb:.1f}x"
        )
        print(line)
        text += line
    (ROOT / "benchmarks" / "results" / "map_scale.md").write_text(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
