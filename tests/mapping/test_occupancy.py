"""The sensor layer of OccupancyMap against octomap-python, voxel for voxel and byte for byte."""

from __future__ import annotations

import math

import numpy as np
import octomap
import pytest

from secure3d._deps import open3d
from secure3d.errors import ConfigError, GeometryError
from secure3d.mapping import OccupancyMap, OccupancyParams
from secure3d.mapping.keys import codes_to_coords
from secure3d.mapping.occupancy import depth_image_points
from secure3d.mapping.octomap_io import read_ot_bytes, read_scan_dat
from secure3d.mapping.store import expand_ranges


@pytest.fixture(scope="module")
def scan(octomap_dir) -> np.ndarray:
    return read_scan_dat(octomap_dir / "scan.dat.bz2")


def octree_voxels(tree: octomap.OcTree) -> np.ndarray:
    """Centres of every finest voxel of an octree (from OctoMap's own .ot serialisation)."""
    leaves = read_ot_bytes(tree.write())
    codes, _ = expand_ranges(leaves.starts, leaves.depths)
    return codes_to_coords(codes, leaves.resolution)


def assert_same_states(ours: OccupancyMap, tree: octomap.OcTree) -> None:
    union = np.unique(
        np.concatenate([ours.occupied_voxels(), ours.free_voxels(), octree_voxels(tree)]), axis=0
    )
    labels = tree.getLabels(union)
    assert (labels != -1).all()
    np.testing.assert_array_equal(ours.classify(union), labels)


@pytest.mark.parametrize(("resolution", "max_range"), [(0.1, None), (0.2, None), (0.1, 5.0)])
def test_real_scan_matches_octomap_voxel_for_voxel(scan, resolution, max_range):
    ours = OccupancyMap(resolution)
    stats = ours.insert_point_cloud(scan, np.zeros(3), max_range)
    tree = octomap.OcTree(resolution)
    tree.insertPointCloud(scan, np.zeros(3), maxrange=-1.0 if max_range is None else max_range)
    assert stats.points_used == scan.shape[0]
    assert_same_states(ours, tree)
    # Same log-odds and same pruned tree: OctoMap's own serialisations are byte-identical.
    assert ours.to_bytes("ot") == tree.write()
    assert ours.to_bytes("bt") == tree.writeBinary()


def test_repeated_scans_accumulate_log_odds_like_octomap(scan, rng):
    """Hits, misses, clamping and occupied-wins over several overlapping scans: identical .ot."""
    res, max_range = 0.2, 6.0
    ours = OccupancyMap(res)
    tree = octomap.OcTree(res)
    for _ in range(6):
        origin = rng.normal(0.0, 0.4, 3)
        sub = scan[rng.random(scan.shape[0]) < 0.3]
        ours.insert_point_cloud(sub, origin, max_range)
        tree.insertPointCloud(sub, origin, maxrange=max_range)
    assert ours.to_bytes("ot") == tree.write()
    assert_same_states(ours, tree)


def test_custom_sensor_model_matches_octomap(scan):
    params = OccupancyParams(
        prob_hit=0.9, prob_miss=0.3, occupancy_threshold=0.6, clamp_min=0.2, clamp_max=0.9
    )
    ours = OccupancyMap(0.2, params)
    tree = octomap.OcTree(0.2)
    tree.setProbHit(0.9)
    tree.setProbMiss(0.3)
    tree.setOccupancyThres(0.6)
    tree.setClampingThresMin(0.2)
    tree.setClampingThresMax(0.9)
    for origin in (np.zeros(3), np.array([0.3, -0.2, 0.1])):
        ours.insert_point_cloud(scan[::3], origin, 4.0)
        tree.insertPointCloud(scan[::3], origin, maxrange=4.0)
    assert ours.to_bytes("ot") == tree.write()
    assert_same_states(ours, tree)


def test_params_log_odds_are_octomaps():
    p = OccupancyParams()
    tree = octomap.OcTree(0.1)
    for ours, ref in (
        (p.hit_log, tree.getProbHitLog()),
        (p.miss_log, tree.getProbMissLog()),
        (p.threshold_log, tree.getOccupancyThresLog()),
        (p.clamp_min_log, tree.getClampingThresMinLog()),
        (p.clamp_max_log, tree.getClampingThresMaxLog()),
    ):
        assert ours == np.float32(ref)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("prob_hit", 0.5),
        ("prob_hit", 1.0),
        ("prob_miss", 0.6),
        ("prob_miss", 0.0),
        ("occupancy_threshold", 0.05),
        ("clamp_min", float("nan")),
        ("clamp_max", 0.4),
        ("prob_hit", "0.7"),
    ],
)
def test_params_validation_names_the_field(field, value):
    with pytest.raises(ConfigError, match=field if field != "clamp_max" else "clamp"):
        OccupancyParams(**{field: value})


@pytest.mark.parametrize("resolution", [0.0, -0.1, float("nan"), float("inf"), "0.1", True])
def test_resolution_validation(resolution):
    with pytest.raises(ConfigError, match="resolution"):
        OccupancyMap(resolution)


@pytest.mark.parametrize(
    "bounds", [([0, 0, 0], [1, 1]), ([0, 0, 0], [1, 1, 0]), ([0, 0, np.nan], [1, 1, 1]), "box"]
)
def test_bounds_validation(bounds):
    with pytest.raises(ConfigError, match="bounds"):
        OccupancyMap(0.1, bounds=bounds)


@pytest.mark.parametrize("max_range", [-1.0, float("nan"), "5"])
def test_max_range_validation(max_range):
    with pytest.raises(ConfigError, match="max_range"):
        OccupancyMap(0.1).insert_point_cloud(np.ones((2, 3)), np.zeros(3), max_range)


def test_nonfinite_and_out_of_range_points_are_skipped_with_counts(rng):
    good = rng.uniform(-3, 3, size=(500, 3))
    bad = np.array([[np.nan, 0, 0], [0, np.inf, 1], [5e3, 0, 0], [0, -1e40, 0]])
    m = OccupancyMap(0.05)  # key range +-1638.4 m
    stats = m.insert_point_cloud(np.concatenate([good, bad]), np.zeros(3))
    assert (stats.skipped_nonfinite, stats.skipped_out_of_range, stats.points_used) == (2, 2, 500)
    clean = OccupancyMap(0.05)
    clean.insert_point_cloud(good, np.zeros(3))
    assert m.to_bytes("ot") == clean.to_bytes("ot")


def test_depth_image_back_projection_matches_open3d_rays():
    """Our pixel convention is Open3D's: points from a ray-cast depth frame lie on the plane."""
    o3d = open3d()
    w, h = 64, 48
    k = np.array([[50.0, 0, 31.0], [0, 55.0, 25.0], [0, 0, 1]])
    # Camera at the origin looking along world +x (camera z), x right = world -y, y down = -z.
    cam2world = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    world2cam = np.eye(4)
    world2cam[:3, :3] = cam2world.T
    rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        o3d.core.Tensor(k), o3d.core.Tensor(world2cam), w, h
    )
    scene = o3d.t.geometry.RaycastingScene()
    plane = o3d.geometry.TriangleMesh.create_box(0.1, 40.0, 40.0).translate([4.0, -20.0, -20.0])
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(plane))
    t_hit = scene.cast_rays(rays)["t_hit"].numpy()  # z-depth for pinhole rays
    pts = depth_image_points(t_hit, k, cam2world, np.zeros(3), None)
    np.testing.assert_allclose(pts[:, 0], 4.0, atol=1e-4, err_msg="points off the plane x = 4")
    d = rays.numpy()[..., 3:].reshape(-1, 3)
    np.testing.assert_allclose(pts, d * t_hit.reshape(-1, 1), atol=1e-4)


def test_depth_image_hits_and_no_returns():
    k = (40.0, 40.0, 20.0, 15.0)
    cam2world = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    origin = np.array([0.0, 0.0, 1.0])
    depth = np.full((30, 40), 3.0)
    depth[:, 20:] = np.inf  # right half: no return
    depth[0, 0] = np.nan
    depth[0, 1] = 0.0
    m = OccupancyMap(0.1)
    stats = m.insert_depth_image(depth, k, cam2world, origin, max_range=5.0)
    assert stats.skipped_nonfinite == 2
    assert stats.clipped == 30 * 20
    occ = m.occupied_voxels()
    assert occ.shape[0] > 0
    # Hits lie on the plane x = 3 (z-depth along world x); no-return rays only cleared space.
    assert np.all(np.abs(occ[:, 0] - 3.0) <= 0.1)
    assert np.all(occ[:, 1] > -0.1), "no occupied voxel on the no-return (world -y) side"
    free = m.free_voxels()
    right = free[:, 1] < -0.5
    reach = np.linalg.norm(free[right] - origin, axis=1)
    assert reach.max() == pytest.approx(5.0, abs=0.2), "no-return beams clear up to max_range"
    with pytest.raises(GeometryError, match="cam2world"):
        m.insert_depth_image(depth, k, 2 * cam2world, origin, 5.0)
    with pytest.raises(GeometryError, match="intrinsics"):
        m.insert_depth_image(depth, (0.0, 40.0, 20.0, 15.0), cam2world, origin, 5.0)


@pytest.mark.parametrize("discretize", [False, True])
def test_z_depth_camera_records_every_hit_it_reports(discretize):
    """A camera whose far limit is a z-depth plane sees hits off its axis farther than that depth.
    With far_kind="depth" every such hit becomes occupied (OctoMap's Euclidean rule would drop
    them, though a planner counts that space as seen), and no returns clear space only within the
    range ``max_range`` (what the sensor surely saw empty)."""
    from secure3d.mapping.occupancy import far_plane_reach

    k = (40.0, 40.0, 20.0, 15.0)
    cam2world = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    origin = np.zeros(3)
    depth = np.full((30, 40), np.inf)
    depth[15, 38] = 5.5  # far right: ray (0.4625, 0.0125, 1), range 6.06 > 5.9
    depth[15, 30] = 6.5  # beyond the z-depth limit: a no return
    hit = cam2world @ (np.array([(38 + 0.5 - 20.0) / 40.0, (15 + 0.5 - 15.0) / 40.0, 1.0]) * 5.5)
    assert np.linalg.norm(hit) > 5.9
    euclid = OccupancyMap(0.1)
    euclid.insert_depth_image(depth, k, cam2world, origin, 5.9, discretize=discretize)
    assert euclid.classify(hit[None])[0] == -1, "OctoMap's rule drops it"
    m = OccupancyMap(0.1)
    stats = m.insert_depth_image(
        depth, k, cam2world, origin, 5.9, discretize=discretize, far_kind="depth"
    )
    assert m.classify(hit[None])[0] == 1 and stats.voxels_occupied == 1
    assert stats.clipped == stats.rays - 1, "every other pixel, 6.5 m included, is a no return"
    free = m.free_voxels()
    along_hit = np.linalg.norm(np.cross(free, hit / np.linalg.norm(hit)), axis=1) < 0.1
    reach = np.linalg.norm(free[~along_hit], axis=1)
    assert reach.max() <= 5.9 + np.sqrt(3) * 0.1 and reach.max() > 5.5
    assert np.linalg.norm(free[along_hit], axis=1).max() > 5.9, "the hit's ray clears up to it"
    corner = np.array([(0.5 - 20.0) / 40.0, (29.5 - 15.0) / 40.0, 1.0]) * 5.9
    assert far_plane_reach((30, 40), k, 5.9) == pytest.approx(np.linalg.norm(corner))
    with pytest.raises(ConfigError, match="max_depth"):
        far_plane_reach((30, 40), k, -1.0)
    with pytest.raises(ConfigError, match="far_kind"):
        m.insert_depth_image(depth, k, cam2world, origin, 5.9, far_kind="sphere")


def test_copy_is_independent(scan):
    m = OccupancyMap(0.2)
    m.insert_point_cloud(scan[::10], np.zeros(3), 4.0)
    c = m.copy()
    before = c.to_bytes("ot")
    m.insert_point_cloud(scan[1::10], np.array([0.5, 0.0, 0.0]), 4.0)
    m.set_claim_boxes([[0, 0, 0]], [[1, 1, 1]])
    assert c.to_bytes("ot") == before
    assert c.claimed_voxels().shape[0] == 0
    assert len(c) < len(m)


def test_voxels_in_box_and_leaves(scan):
    m = OccupancyMap(0.2)
    m.insert_point_cloud(scan, np.zeros(3), 5.0)
    lo, hi = np.array([-1.0, -3.0, -0.5]), np.array([2.0, 1.0, 1.5])
    centres, trust = m.voxels_in_box(lo, hi)
    every = np.concatenate([m.occupied_voxels(), m.free_voxels()])
    inside = every[np.all((every >= lo) & (every <= hi), axis=1)]
    assert {tuple(c) for c in np.round(centres, 6)} == {tuple(c) for c in np.round(inside, 6)}
    np.testing.assert_array_equal(trust, np.where(m.classify(centres) == 1, 4, 3))
    # The pruned form covers exactly the same volume.
    lc, sizes, logodds = m.leaves()
    assert math.isclose(float(np.sum(sizes**3)), len(m) * 0.2**3, rel_tol=1e-9)
    assert sizes.max() > 0.2, "a scan's free space prunes into bigger leaves"
    np.testing.assert_array_equal(
        m.classify(lc), (logodds >= m.params.threshold_log).astype(np.int8)
    )


def test_cube_closing_equals_scipy(rng):
    """The separable closing used for ``close_gaps`` gives scipy's cells, borders included."""
    from scipy import ndimage

    from secure3d.mapping.obstacle_boxes import binary_closing_cube as _binary_closing_cube

    cube = np.ones((3, 3, 3), bool)
    for _ in range(25):
        grid = rng.random(tuple(rng.integers(1, 20, 3))) < rng.uniform(0.05, 0.7)
        for iterations in (1, 2, 3):
            expected = ndimage.binary_closing(grid, structure=cube, iterations=iterations)
            np.testing.assert_array_equal(_binary_closing_cube(grid, iterations), expected)


def test_sparse_closing_equals_the_dense_closing(rng):
    """The kernel that walks only the dilated cells gives the dense closing's cells (union the
    input), borders included, for sparse and dense sets and radii 1-3."""
    from secure3d.mapping._closing_kernel import sparse_closing
    from secure3d.mapping.obstacle_boxes import binary_closing_cube

    for _ in range(40):
        shape = tuple(int(v) for v in rng.integers(1, 24, 3))
        grid = rng.random(shape) < rng.choice([0.01, 0.05, 0.3, 0.7])
        for radius in (1, 2, 3):
            expected = binary_closing_cube(grid, radius) | grid
            got = sparse_closing(np.argwhere(grid), shape, radius)
            np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize("span", [5000, 1 << 40])
def test_voxel_table_grows_by_the_blocks_it_adds(rng, span):
    """add_logodds grows when the blocks actually added need it (possibly several times within one
    call), and updates every code exactly once, as a dict would; get, set and the sorted listings
    agree with the dict. Dense codes (most share 4 x 4 x 4 blocks) and scattered ones (one voxel a
    block)."""
    from secure3d.mapping.store import BLOCK_BITS, VoxelTable

    table, ref = VoxelTable(capacity=16), {}
    for _ in range(6):
        codes = rng.choice(span, size=rng.integers(1, 3000), replace=False).astype(np.int64)
        delta = float(rng.uniform(-0.5, 0.9))
        table.add_logodds(codes, delta, -2.0, 3.5)
        for c in codes.tolist():
            ref[c] = float(np.clip(np.float32(ref.get(c, 0.0)) + np.float32(delta), -2.0, 3.5))
        blocks = len({c >> BLOCK_BITS for c in ref})
        assert table.count == len(ref) and table.nblocks == blocks <= table.capacity
    got_codes, got_vals = table.items()
    assert got_codes.tolist() == sorted(ref)
    np.testing.assert_allclose(got_vals, [ref[c] for c in sorted(ref)], rtol=1e-6)
    probe = np.concatenate([got_codes[::7], rng.integers(0, span, 500), [-1]])
    want = [ref.get(c, np.nan) if c >= 0 else np.nan for c in probe.tolist()]
    np.testing.assert_allclose(table.get(probe), want, rtol=1e-6)
    at_least = [c for c in sorted(ref) if ref[c] >= 0.5]
    assert table.codes_at_least(0.5).tolist() == at_least
    # codes already present take no room: the capacity stays
    cap = table.capacity
    table.add_logodds(got_codes, -0.1, -2.0, 3.5)
    assert table.capacity == cap and table.count == len(ref)
    # set overwrites and inserts; a copy is independent
    copy = table.copy()
    fresh = np.array([span + 3, span + 64 * 9], np.int64)
    table.set(np.concatenate([got_codes[:2], fresh]), np.array([1.0, -1.0, 2.0, 3.0], np.float32))
    np.testing.assert_array_equal(table.get(got_codes[:2]), [1.0, -1.0])
    assert table.count == len(ref) + 2 and copy.count == len(ref)
    assert np.isnan(copy.get(fresh)).all()


def test_voxel_table_hash_keeps_neighbouring_blocks_in_one_cache_line(rng):
    """The blocks of a 2 x 2 x 2 group (block codes equal but for the low three bits) take the
    slots of one aligned run of eight in an empty table, one each; the listing and the values are
    those of a dict, whatever the slots (a table of many such groups, several per run)."""
    from secure3d.mapping.store import BLOCK_BITS, VoxelTable

    table = VoxelTable(capacity=1 << 16)
    group = int(rng.integers(0, 1 << 30)) << 3
    codes = np.array([(group + i) << BLOCK_BITS for i in range(8)], np.int64)
    table.add_logodds(codes, 0.85, -2.0, 3.5)
    slots = np.flatnonzero(table.bkeys != -1)
    assert len(slots) == 8 and slots[0] % 8 == 0 and slots[-1] == slots[0] + 7
    np.testing.assert_array_equal(np.sort(table.bkeys[slots]), codes >> BLOCK_BITS)

    crowded, ref = VoxelTable(capacity=16), {}
    for _ in range(4):
        blocks = rng.integers(0, 64, 200) + (rng.integers(0, 4, 200) << 20)  # few groups, dense
        codes = np.unique((blocks << BLOCK_BITS) + rng.integers(0, 64, 200)).astype(np.int64)
        crowded.add_logodds(codes, -0.4, -2.0, 3.5)
        for c in codes.tolist():
            ref[c] = float(np.clip(np.float32(ref.get(c, 0.0)) + np.float32(-0.4), -2.0, 3.5))
    got_codes, got_vals = crowded.items()
    assert got_codes.tolist() == sorted(ref)
    np.testing.assert_array_equal(got_vals, np.float32([ref[c] for c in sorted(ref)]))


def test_voxel_table_set_rejects_nan_and_mismatched_values():
    """NaN marks an unknown voxel, so a NaN value cannot be stored; values must match codes."""
    from secure3d.mapping.store import VoxelTable

    table = VoxelTable()
    with pytest.raises(GeometryError, match="NaN"):
        table.set(np.array([5], np.int64), np.array([np.nan], np.float32))
    with pytest.raises(GeometryError, match="values"):
        table.set(np.array([5, 6], np.int64), np.array([1.0], np.float32))
    assert table.count == 0


def test_tiles_round_trip_and_count(rng):
    """codes_to_tiles and tiles_to_codes are inverse (as sets; ascending within a tile), the
    voxel count is the masks' bits, and mismatched or negative input raises."""
    from secure3d.mapping.morton import codes_to_tiles, tile_voxel_count, tiles_to_codes

    codes = np.unique(rng.integers(0, 1 << 20, 5000)).astype(np.int64)
    codes = np.concatenate([codes, (77 << 6) + np.arange(64)])  # one whole tile
    codes = np.unique(codes)
    blocks, masks = codes_to_tiles(rng.permutation(codes))
    assert np.all(np.diff(blocks) > 0) and np.all(masks != 0)
    assert tile_voxel_count(masks) == codes.size
    np.testing.assert_array_equal(tiles_to_codes(blocks, masks), codes)
    assert masks[np.searchsorted(blocks, 77)] == np.uint64(0xFFFFFFFFFFFFFFFF)
    with pytest.raises(GeometryError, match="masks"):
        tiles_to_codes(blocks, masks[:-1])
    with pytest.raises(GeometryError, match="non-negative"):
        codes_to_tiles(np.array([-3, 4]))
    with pytest.raises(GeometryError, match="tile masks.*float64"):
        tile_voxel_count(np.array([1.5]))
    with pytest.raises(GeometryError, match="tile masks.*int64"):
        tiles_to_codes(np.array([1]), np.array([-1]))


@pytest.mark.parametrize("span", [5000, 1 << 40])
def test_voxel_table_tile_updates_equal_code_updates(rng, span):
    """add_logodds_tiles gives the values add_logodds gives for the same voxels, bit for bit, with
    whole tiles (the vectorised path) and partial ones, growing several times; a LeafLayer with
    coarse leaves splits them first, as with codes."""
    from secure3d.mapping.morton import codes_to_tiles
    from secure3d.mapping.store import LeafLayer, VoxelTable

    by_tiles, by_codes = VoxelTable(capacity=16), VoxelTable(capacity=16)
    for _ in range(6):
        codes = rng.choice(span, size=rng.integers(1, 3000), replace=False).astype(np.int64)
        whole = (rng.integers(0, span >> 6, 3)[:, None] << 6) + np.arange(64)
        codes = np.unique(np.concatenate([codes, whole.ravel()]))
        delta = float(rng.choice([-0.4, 0.85, -2.5]))
        by_codes.add_logodds(codes, delta, -2.0, 3.5)
        by_tiles.add_logodds_tiles(*codes_to_tiles(codes), delta, -2.0, 3.5)
        assert by_tiles.count == by_codes.count and by_tiles.nblocks == by_codes.nblocks
    for a, b in zip(by_tiles.items(), by_codes.items(), strict=True):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(GeometryError, match="masks"):
        by_tiles.add_logodds_tiles(np.array([1, 2]), np.array([3], np.uint64), -0.4, -2.0, 3.5)
    with pytest.raises(GeometryError, match="non-negative integers"):  # not cast silently
        by_tiles.add_logodds_tiles(np.array([1, 2]), np.array([3.0, 1.5]), -0.4, -2.0, 3.5)

    coarse_tiles, coarse_codes = LeafLayer(), LeafLayer()
    for layer in (coarse_tiles, coarse_codes):  # one depth-14 leaf (4096 voxels) and one voxel
        layer.set_leaves(np.array([0, 1 << 20]), np.array([14, 16]), np.array([1.0, 2.0]))
    codes = np.array([5, 70, 4095, (1 << 20) + 1], np.int64)
    coarse_codes.add_logodds(codes, -0.4, -2.0, 3.5)
    coarse_tiles.add_logodds_tiles(*codes_to_tiles(codes), -0.4, -2.0, 3.5)
    for a, b in zip(coarse_tiles.leaves(), coarse_codes.leaves(), strict=True):
        np.testing.assert_array_equal(a, b)
