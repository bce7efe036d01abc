"""Benchmark the occupancy store against octomap-python (the reference OctoMap).

For each case the same cloud is inserted into an :class:`~secure3d.mapping.OccupancyMap` and into
an ``octomap.OcTree`` and the table reports points/s for both, the speed ratio, and the percentage
of voxels whose state (unknown/free/occupied) agrees over the union of both maps' voxels (queried
with octomap's own ``getLabels`` and our ``classify``). Cases: the real scan (scan.dat.bz2, 88,206
points, sensor at the origin) at 0.05, 0.1 and 0.2 m with and without a 5 m maximum range, and a
synthetic 320x240 depth frame; the frame and the scan at 0.1 m also discretised (OctoMap's
``insertPointCloud(..., discretize=true)``, as the simulator inserts frames). Then random point
queries and box extraction are timed.

Times are CPU seconds (``time.process_time``, best of ``--repeat``): both libraries are single
threaded and the benchmark machine is shared. Run::

    .venv/bin/python benchmarks/bench_mapping.py [--repeat 3] [--data ../shared/data/octomap]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import octomap

from secure3d.mapping import OccupancyMap
from secure3d.mapping.boxes import merge_cells_budget
from secure3d.mapping.keys import codes_to_coords, coords_to_keys
from secure3d.mapping.occupancy import depth_image_points
from secure3d.mapping.octomap_io import read_ot_bytes, read_scan_dat
from secure3d.mapping.store import expand_ranges

DEFAULT_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "octomap"
TARGET_RATIO = 3.0
TARGET_AGREEMENT = 99.9


def synthetic_depth_frame() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """A 320x240 z-depth frame of a room with three boxes and an open doorway (inf pixels).

    Returns depth (240, 320), K (3, 3), cam2world (3, 3), origin (3,), max_range.
    """
    w, h = 320, 240
    k = np.array([[160.0, 0.0, 160.0], [0.0, 160.0, 120.0], [0.0, 0.0, 1.0]])  # 90 deg HFOV
    # Camera looks along world +x; camera x (right) = world -y, camera y (down) = world -z.
    cam2world = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    origin = np.array([0.0, 0.0, 1.2])
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    ray = np.stack([(u - k[0, 2]) / k[0, 0], (v - k[1, 2]) / k[1, 1], np.ones_like(u)], axis=-1)
    d = ray @ cam2world.T  # world direction per unit z-depth
    room_lo, room_hi = np.array([-1.0, -4.0, 0.0]), np.array([9.0, 4.0, 3.0])
    with np.errstate(divide="ignore", invalid="ignore"):
        t_exit = np.where(d > 0, (room_hi - origin) / d, (room_lo - origin) / d)
        t_exit[~np.isfinite(t_exit) | (t_exit <= 0)] = np.inf
    depth = t_exit.min(axis=-1)
    hit = origin + depth[..., None] * d
    doorway = (hit[..., 0] > 8.99) & (np.abs(hit[..., 1]) < 1.0) & (hit[..., 2] < 2.2)
    depth[doorway] = np.inf
    for lo, hi in (([2.0, -1.5, 0.0], [2.6, -0.5, 1.0]), ([4.0, 1.0, 0.0], [5.0, 2.5, 2.0]),
                   ([3.0, -3.0, 1.5], [3.4, -2.0, 2.5])):  # fmt: skip
        lo_a, hi_a = np.array(lo), np.array(hi)
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (lo_a - origin) / d
            t1 = (hi_a - origin) / d
        t_near = np.nanmax(np.minimum(t0, t1), axis=-1)
        t_far = np.nanmin(np.maximum(t0, t1), axis=-1)
        enters = (t_near <= t_far) & (t_near > 0)
        depth = np.where(enters & (t_near < depth), t_near, depth)
    return depth, k, cam2world, origin, 6.0


def best_cpu(fn, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return best


def octree_voxel_centres(tree: octomap.OcTree) -> np.ndarray:
    """Centres of every finest-level voxel an octree knows (pruned leaves expanded).

    Read from OctoMap's own ``.ot`` serialisation (``write`` does not modify the tree).
    """
    leaves = read_ot_bytes(tree.write())
    codes, _ = expand_ranges(leaves.starts, leaves.depths)
    return codes_to_coords(codes, leaves.resolution)


def agreement(ours: OccupancyMap, tree: octomap.OcTree) -> tuple[float, int]:
    """Percentage of the union of both maps' voxels with the same state, and the union size."""
    union = np.unique(
        np.concatenate([ours.occupied_voxels(), ours.free_voxels(), octree_voxel_centres(tree)]),
        axis=0,
    )
    same = ours.classify(union) == tree.getLabels(union)
    return 100.0 * float(same.mean()) if union.size else 100.0, union.shape[0]


def insertion_case(
    name: str,
    points: np.ndarray,
    origin: np.ndarray,
    resolution: float,
    max_range: float | None,
    repeat: int,
    discretize: bool = False,
) -> dict:
    def ours_insert() -> OccupancyMap:
        m = OccupancyMap(resolution)
        m.insert_point_cloud(points, origin, max_range, discretize=discretize)
        return m

    def ref_insert() -> octomap.OcTree:
        t = octomap.OcTree(resolution)
        t.insertPointCloud(
            points, origin, maxrange=-1.0 if max_range is None else max_range, discretize=discretize
        )
        return t

    t_ours = best_cpu(ours_insert, repeat)
    t_ref = best_cpu(ref_insert, repeat)
    agree, n_union = agreement(ours_insert(), ref_insert())
    n = points.shape[0]
    return {
        "case": name,
        "ours": n / t_ours,
        "octomap": n / t_ref,
        "ratio": t_ref / t_ours,
        "agree": agree,
        "voxels": n_union,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="shared OctoMap data dir")
    parser.add_argument("--repeat", type=int, default=3, help="timing repetitions (best kept)")
    args = parser.parse_args()

    missing = [n for n in ("scan.dat.bz2", "geb079.bt") if not (args.data / n).is_file()]
    if missing:
        parser.error(f"--data {str(args.data)!r}: no {' or '.join(missing)} there")
    scan = read_scan_dat(args.data / "scan.dat.bz2")
    origin = np.zeros(3)
    # Warm-up: load the numba kernels from their cache (or compile them) outside the timings.
    warm = OccupancyMap(0.2)
    warm.insert_point_cloud(scan[:100], origin)
    warm.classify(scan[:10])
    warm.known_obstacle_boxes()

    rows = []
    for res in (0.05, 0.1, 0.2):
        for mr in (None, 5.0):
            name = f"scan.dat {res:.2f} m, " + ("no max range" if mr is None else f"max {mr:g} m")
            rows.append(insertion_case(name, scan, origin, res, mr, args.repeat))
    depth, k, cam2world, cam_origin, max_range = synthetic_depth_frame()
    frame = depth_image_points(depth, k, cam2world, cam_origin, max_range)
    frame = frame[np.all(np.isfinite(frame), axis=1)]
    for disc in (False, True):
        rows.append(
            insertion_case(
                "depth 320x240 0.05 m, max 6 m" + (", discretised" if disc else ""),
                frame,
                cam_origin,
                0.05,
                max_range,
                args.repeat,
                disc,
            )
        )
    rows.append(
        insertion_case("scan.dat 0.10 m, discretised", scan, origin, 0.1, None, args.repeat, True)
    )

    print(f"\nInsertion (CPU time, best of {args.repeat}; target >= {TARGET_RATIO:g}x, "
          f">= {TARGET_AGREEMENT}% agreement)")  # fmt: skip
    print(f"{'case':<34} {'ours pts/s':>12} {'octomap pts/s':>14} {'ratio':>7} "
          f"{'agree %':>9} {'voxels':>9}")  # fmt: skip
    for r in rows:
        ok = r["ratio"] >= TARGET_RATIO and r["agree"] >= TARGET_AGREEMENT
        print(f"{r['case']:<34} {r['ours']:>12,.0f} {r['octomap']:>14,.0f} {r['ratio']:>6.1f}x "
              f"{r['agree']:>9.4f} {r['voxels']:>9,} {'ok' if ok else 'MISS'}")  # fmt: skip

    # Random point queries on the 0.1 m map of the scan.
    ours = OccupancyMap(0.1)
    ours.insert_point_cloud(scan, origin)
    tree = octomap.OcTree(0.1)
    tree.insertPointCloud(scan, origin)
    rng = np.random.default_rng(0)
    lo, hi = scan.min(axis=0), scan.max(axis=0)
    queries = rng.uniform(lo, hi, size=(1_000_000, 3))
    t_ours = best_cpu(lambda: ours.classify(queries), args.repeat)
    t_ref = best_cpu(lambda: tree.getLabels(queries), args.repeat)
    same = float((ours.classify(queries) == tree.getLabels(queries)).mean()) * 100.0
    print("\nRandom point queries (1e6 points in the scan's box, 0.1 m map)")
    print(f"  ours classify   {queries.shape[0] / t_ours:>14,.0f} points/s")
    print(f"  octomap labels  {queries.shape[0] / t_ref:>14,.0f} points/s   "
          f"ratio {t_ref / t_ours:.1f}x, same label {same:.4f} %")  # fmt: skip

    # Box extraction on real maps.
    print("\nBox extraction (known obstacle voxels -> merged boxes)")
    geb = OccupancyMap.read_bt(args.data / "geb079.bt")
    for label, m in (("geb079.bt (0.08 m)", geb), ("scan.dat 0.1 m", ours)):
        keys, _ = coords_to_keys(m.known_obstacle_voxels(), m.resolution)
        n_vox = keys.shape[0]
        t_box = best_cpu(lambda keys=keys: merge_cells_budget(keys), args.repeat)
        n_box = merge_cells_budget(keys)[0].shape[0]
        print(f"  {label:<20} {n_vox:>8,} voxels -> {n_box:>7,} boxes "
              f"({n_box / max(n_vox, 1):.3f} boxes/voxel) in {1e3 * t_box:.1f} ms")  # fmt: skip


if __name__ == "__main__":
    main()
