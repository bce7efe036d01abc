"""Keys, Morton codes and ray casting, checked against octomap-python (the reference OctoMap)."""

from __future__ import annotations

import numpy as np
import octomap
import pytest

from secure3d.errors import GeometryError
from secure3d.mapping._scan_chunked import _scan_chunked_kernel
from secure3d.mapping.keys import (
    KEY_LIMIT,
    codes_to_coords,
    coords_to_keys,
    keys_to_coords,
    morton_decode,
    morton_encode,
    ray_keys,
    scan_update,
)
from secure3d.mapping.octomap_io import read_scan_dat
from secure3d.mapping.raycast import _clipped_ends, check_origin


@pytest.fixture(scope="module")
def scan(octomap_dir) -> np.ndarray:
    return read_scan_dat(octomap_dir / "scan.dat.bz2")


def octomap_key(tree: octomap.OcTree, p: np.ndarray) -> tuple[int, int, int]:
    k = tree.coordToKey(np.asarray(p, dtype=np.float64))
    return k[0], k[1], k[2]


def test_morton_round_trip_and_child_index(rng):
    keys = rng.integers(0, KEY_LIMIT, size=(5000, 3))
    codes = morton_encode(keys)
    np.testing.assert_array_equal(morton_decode(codes), keys)
    # OctoMap's computeChildIdx at tree level l uses bit (15 - l) of each key: x + 2y + 4z.
    for level in (0, 7, 15):
        bit = 15 - level
        expected = (
            ((keys[:, 0] >> bit) & 1)
            + 2 * ((keys[:, 1] >> bit) & 1)
            + 4 * ((keys[:, 2] >> bit) & 1)
        )
        np.testing.assert_array_equal((codes >> (3 * bit)) & 7, expected)
    # Sorting codes is depth-first order: a parent's 8 children form a contiguous run.
    assert np.all(np.diff(np.sort(codes)) > 0)


@pytest.mark.parametrize("resolution", [0.05, 0.1, 0.13, 0.2])
def test_keys_match_octomap_including_voxel_borders(rng, resolution):
    tree = octomap.OcTree(resolution)
    random = rng.uniform(-50.0, 50.0, size=(300, 3))
    borders = rng.integers(-300, 300, size=(300, 3)) * resolution  # exactly on voxel borders
    nudged = borders + rng.choice([-1e-7, 1e-7], size=borders.shape)
    pts = np.concatenate([random, borders, nudged])
    keys, valid = coords_to_keys(pts, resolution)
    assert valid.all()
    expected = np.array([octomap_key(tree, p) for p in pts])
    np.testing.assert_array_equal(keys, expected)
    np.testing.assert_allclose(
        keys_to_coords(keys, resolution),
        [tree.keyToCoord(tree.coordToKey(p)) for p in pts],
        atol=1e-9,
        err_msg="voxel centres differ from OctoMap's keyToCoord",
    )


def test_keys_reject_nonfinite_and_out_of_range():
    res = 0.1
    limit = 32768 * res
    pts = np.array(
        [[np.nan, 0, 0], [0, np.inf, 0], [0, 0, -np.inf], [limit + 1.0, 0, 0], [-limit - 1, 0, 0]]
    )
    _, valid = coords_to_keys(pts, res)
    assert not valid.any()
    keys, valid = coords_to_keys([[limit - 0.5 * res, -limit + 0.5 * res, 0.0]], res)
    assert valid.all() and keys[0, 0] == KEY_LIMIT - 1 and keys[0, 1] == 0


def octomap_ray_free_keys(resolution: float, origin: np.ndarray, end: np.ndarray) -> set:
    """Free voxels OctoMap creates for a one-point scan: exactly its ray keys (no pruning is
    possible: one ray crosses at most 4 voxels of a 2x2x2 block)."""
    tree = octomap.OcTree(resolution)
    tree.insertPointCloud(end[None], origin)
    _, free = tree.extractPointCloud()
    return {octomap_key(tree, c) for c in free}


def test_ray_keys_match_octomap_on_random_and_degenerate_rays(rng):
    cases = []
    for res in (0.05, 0.1, 0.13):
        for _ in range(40):
            cases.append((res, rng.uniform(-2, 2, 3), rng.uniform(-8, 8, 3)))
        # Axis-aligned, diagonal and voxel-border rays stress the DDA's tie-breaking.
        cases.append((res, np.zeros(3), np.array([3.0, 0.0, 0.0])))
        cases.append((res, np.zeros(3), np.array([-2.0, -2.0, -2.0])))
        cases.append((res, np.array([res, 2 * res, 0.0]), np.array([40 * res, -17 * res, 9 * res])))
        cases.append((res, np.array([0.01, 0.02, 0.03]), np.array([0.01, 0.02, 5.03])))
    for res, origin, end in cases:
        ours = ray_keys(origin, end, res)
        ref = octomap_ray_free_keys(res, origin, end)
        assert {tuple(k) for k in ours} == ref, f"res {res} origin {origin} end {end}"
        assert len(ours) == len(ref), "a voxel was listed twice"


def test_ray_keys_geometry(rng):
    res = 0.1
    for _ in range(50):
        origin, end = rng.uniform(-3, 3, 3), rng.uniform(-3, 3, 3)
        keys = ray_keys(origin, end, res)
        (ko,), (ke,) = coords_to_keys(origin[None], res)[0], coords_to_keys(end[None], res)[0]
        if np.array_equal(ko, ke):
            assert keys.shape[0] == 0
            continue
        np.testing.assert_array_equal(keys[0], ko, err_msg="the origin voxel comes first")
        assert not np.any(np.all(keys == ke, axis=1)), "the end voxel is excluded"
        steps = np.abs(np.diff(keys, axis=0))
        assert np.all(steps.sum(axis=1) == 1), "consecutive voxels share a face"
        # Every voxel touches the segment: distance from the voxel box to the segment ~ 0.
        lo = (keys - 32768) * res
        t = np.linspace(0.0, 1.0, 4001)
        seg = origin + t[:, None] * (end - origin)
        gap = np.maximum(lo[:, None] - seg[None], 0) + np.maximum(
            seg[None] - (lo[:, None] + res), 0
        )
        dist = np.linalg.norm(gap, axis=2).min(axis=1)
        assert dist.max() < 1e-3 * res + np.linalg.norm(end - origin) / 4000


def octomap_state_counts(tree: octomap.OcTree) -> tuple[int, int]:
    """Finest-level (occupied, free) voxel counts of an octree, pruned leaves expanded."""
    occ = free = 0
    for leaf in tree.begin_leafs():
        n = 8 ** (16 - leaf.getDepth())
        if tree.isNodeOccupied(leaf):
            occ += n
        else:
            free += n
    return occ, free


@pytest.mark.parametrize("max_range", [None, 5.0])
def test_scan_update_matches_octomap(scan, max_range):
    res = 0.2
    origin = np.array([0.05, -0.1, 0.2])
    upd = scan_update(scan, origin, res, max_range)
    tree = octomap.OcTree(res)
    tree.insertPointCloud(scan, origin, maxrange=-1.0 if max_range is None else max_range)
    assert np.intersect1d(upd.free, upd.occupied).size == 0, "occupied must win over free"
    assert np.unique(upd.free).size == upd.free.size
    np.testing.assert_array_equal(tree.getLabels(codes_to_coords(upd.free, res)), 0)
    np.testing.assert_array_equal(tree.getLabels(codes_to_coords(upd.occupied, res)), 1)
    assert octomap_state_counts(tree) == (upd.occupied.size, upd.free.size)
    if max_range is not None:
        dist = np.linalg.norm(scan - origin, axis=1)
        assert upd.clipped == int(np.sum(dist > max_range)) > 0
        reach = np.linalg.norm(codes_to_coords(upd.free, res) - origin, axis=1)
        assert reach.max() <= max_range + res * np.sqrt(3), "clipped beams clear up to max range"


def test_chunked_kernel_equals_dense_kernel(scan):
    res = 0.1
    o = np.zeros(3, np.float32)
    dense = scan_update(scan, o, res)
    ends, keys, status, _, _ = _clipped_ends(scan, o, res, -1.0, -1.0)
    free, occ = _scan_chunked_kernel(ends, keys, status, o, res)
    np.testing.assert_array_equal(np.sort(free), np.sort(dense.free))
    np.testing.assert_array_equal(np.sort(occ), np.sort(dense.occupied))


@pytest.mark.parametrize("resolution", [0.1, 0.05])
def test_the_dense_kernel_gives_the_same_bits_in_any_number_of_parts(scan, resolution):
    """The rays are traced in threads, each into a bitmap of its own, or-ed together: the free and
    occupied bitmaps and the occupied voxels' order do not depend on how many parts there are."""
    from secure3d.mapping import scan as scan_module

    o = check_origin([0.1, -0.2, 0.3], resolution)
    ends, keys, status, lo, hi = _clipped_ends(scan, o, resolution, 6.0, 6.0)
    lo, dims = scan_module._dense_box(lo, hi)
    args = (ends, keys, status, o, resolution, lo, dims)
    one = scan_module._dense_trace(*args, 1)
    assert one[0].size > 1000 and np.count_nonzero(one[1]) > 1000
    for parts in (2, 3, 7):
        for got, want in zip(scan_module._dense_trace(*args, parts), one, strict=True):
            np.testing.assert_array_equal(got, want)
    assert scan_module._trace_parts(100) == 1


def test_scan_threads_follow_the_environment(monkeypatch):
    from secure3d.mapping import scan as scan_module

    monkeypatch.setenv("SECURE3D_SCAN_THREADS", "3")
    assert scan_module.scan_threads() == 3
    assert scan_module._trace_parts(3 * scan_module._RAYS_PER_PART) == 3
    assert scan_module._trace_parts(2 * scan_module._RAYS_PER_PART) == 2
    for bad in ("0", "two", "-1"):
        monkeypatch.setenv("SECURE3D_SCAN_THREADS", bad)
        with pytest.raises(GeometryError, match="SECURE3D_SCAN_THREADS.*>= 1"):
            scan_module.scan_threads()
    monkeypatch.delenv("SECURE3D_SCAN_THREADS")
    assert 1 <= scan_module.scan_threads() <= scan_module._MAX_SCAN_THREADS


def test_scan_tiles_hold_the_scan_updates_voxels(scan, monkeypatch):
    """scan_tiles lists the free voxels of scan_update as tiles (each tile once, nonzero masks),
    with the same occupied voxels and counts, from the dense kernel and from the chunked one."""
    from secure3d.mapping import scan as scan_module
    from secure3d.mapping.keys import scan_tiles, tile_voxel_count

    o = np.array([0.1, -0.2, 0.3])
    for limit in (scan_module._DENSE_VOXEL_LIMIT, 0):  # 0: every scan takes the chunked kernel
        monkeypatch.setattr(scan_module, "_DENSE_VOXEL_LIMIT", limit)
        upd, tiles = scan_update(scan, o, 0.1, 6.0), scan_tiles(scan, o, 0.1, 6.0)
        assert np.unique(tiles.blocks).size == tiles.blocks.size and np.all(tiles.masks != 0)
        assert tile_voxel_count(tiles.masks) == upd.free.size
        np.testing.assert_array_equal(np.sort(tiles.free()), np.sort(upd.free))
        np.testing.assert_array_equal(tiles.occupied, upd.occupied)
        assert tuple(tiles[3:]) == tuple(upd[2:])


def test_bad_points_are_counted_and_ignored(rng):
    res = 0.01  # key range +-327.68 m
    good = rng.uniform(-2, 2, size=(200, 3))
    bad = np.array([[np.nan, 0, 0], [1.0, np.inf, 0], [0, 0, -np.inf], [1e6, 0, 0], [0, 1e300, 0]])
    upd = scan_update(np.concatenate([good, bad]), np.zeros(3), res)
    ref = scan_update(good, np.zeros(3), res)
    assert (upd.points_used, upd.skipped_nonfinite, upd.skipped_out_of_range) == (200, 3, 2)
    np.testing.assert_array_equal(np.sort(upd.free), np.sort(ref.free))
    np.testing.assert_array_equal(np.sort(upd.occupied), np.sort(ref.occupied))


def test_bad_origin_and_shapes_raise():
    with pytest.raises(GeometryError, match="origin"):
        scan_update(np.zeros((3, 3)), [np.nan, 0, 0], 0.1)
    with pytest.raises(GeometryError, match="origin"):
        scan_update(np.zeros((3, 3)), [1e6, 0, 0], 0.1)
    with pytest.raises(GeometryError, match=r"shape \(n, 3\)"):
        scan_update(np.zeros((3, 2)), np.zeros(3), 0.1)


@pytest.mark.parametrize("max_range", [None, 5.0])
def test_discretized_scan_matches_octomap(scan, rng, max_range):
    """``discretize=True`` is OctoMap's ``insertPointCloud(..., discretize=true)`` voxel for voxel,
    on the real scan and on a dense cloud (many points per voxel, as a depth camera gives)."""
    res = 0.2
    origin = np.array([0.05, -0.1, 0.2])
    dense = origin + rng.normal(size=(20000, 3)) * [2.0, 2.0, 0.5]
    for cloud in (scan, dense):
        upd = scan_update(cloud, origin, res, max_range, discretize=True)
        tree = octomap.OcTree(res)
        tree.insertPointCloud(
            cloud, origin, maxrange=-1.0 if max_range is None else max_range, discretize=True
        )
        assert np.intersect1d(upd.free, upd.occupied).size == 0
        np.testing.assert_array_equal(tree.getLabels(codes_to_coords(upd.free, res)), 0)
        np.testing.assert_array_equal(tree.getLabels(codes_to_coords(upd.occupied, res)), 1)
        assert octomap_state_counts(tree) == (upd.occupied.size, upd.free.size)
        voxels = np.unique(coords_to_keys(cloud, res)[0], axis=0)
        assert upd.rays == len(voxels) < len(cloud), "one ray per distinct end voxel"
        assert upd.points_used == len(cloud)
        exact = scan_update(cloud, origin, res, max_range)
        if max_range is None:
            np.testing.assert_array_equal(np.sort(upd.occupied), np.sort(exact.occupied))


def test_discretized_scan_counts_bad_points(rng):
    res = 0.01
    good = rng.uniform(-2, 2, size=(200, 3))
    bad = np.array([[np.nan, 0, 0], [1.0, np.inf, 0], [1e6, 0, 0], [0, 1e300, 0]])
    upd = scan_update(np.concatenate([good, bad]), np.zeros(3), res, discretize=True)
    ref = scan_update(good, np.zeros(3), res, discretize=True)
    assert (upd.points_used, upd.skipped_nonfinite, upd.skipped_out_of_range) == (200, 2, 2)
    np.testing.assert_array_equal(upd.free, ref.free)
    np.testing.assert_array_equal(upd.occupied, ref.occupied)


def test_box_codes_are_the_codes_of_every_box_cell(rng):
    from secure3d.mapping.claim import box_cells as _box_cells
    from secure3d.mapping.keys import box_codes

    lo = rng.integers(32700, 32800, (30, 3))
    hi = lo + rng.integers(-2, 12, (30, 3))  # some boxes empty along an axis
    np.testing.assert_array_equal(box_codes(lo, hi), morton_encode(_box_cells(lo, hi)))
    assert box_codes(np.empty((0, 3)), np.empty((0, 3))).size == 0
    with pytest.raises(GeometryError, match="keys must lie"):
        box_codes([[0, 0, -1]], [[1, 1, 1]])


def test_clear_range_shortens_what_long_beams_clear(scan):
    origin = np.zeros(3)
    full = scan_update(scan, origin, 0.2, 5.0)
    short = scan_update(scan, origin, 0.2, 5.0, clear_range=3.0)
    np.testing.assert_array_equal(np.sort(short.occupied), np.sort(full.occupied))
    assert short.clipped == full.clipped > 0
    reach = np.linalg.norm(codes_to_coords(short.free, 0.2), axis=1)
    hits = np.linalg.norm(codes_to_coords(full.occupied, 0.2), axis=1)
    assert np.isin(short.free, full.free).all() and short.free.size < full.free.size
    assert reach.max() <= max(hits.max(), 3.0) + 0.2 * np.sqrt(3)
    with pytest.raises(GeometryError, match="clear_range"):
        scan_update(scan, origin, 0.2, 5.0, clear_range=6.0)
