"""The spatial index over boxes answers every query exactly as the brute-force loops do."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.errors import GeometryError
from secure3d.geometry.box_index import BoxIndex
from secure3d.geometry.polytope import (
    cones_blocked,
    inside_any_box,
    min_box_distance,
    segments_blocked,
)
from secure3d.planning.lookback import min_box_distance_all


def _voxel_boxes(rng: np.random.Generator, m: int, res: float = 0.1) -> tuple:
    """Boxes on a voxel lattice (shared faces, duplicates, long walls and single voxels), as merged
    voxel maps give them."""
    lo_k = rng.integers(0, 60, size=(m, 3))
    size = rng.integers(1, 4, size=(m, 3))
    walls = rng.random(m) < 0.2
    size[walls, rng.integers(0, 3, walls.sum())] = rng.integers(10, 40, walls.sum())
    lo = lo_k * res
    hi = (lo_k + size) * res
    dup = rng.integers(0, m, m // 20)
    return np.concatenate([lo, lo[dup]]), np.concatenate([hi, hi[dup]])


def _queries(rng: np.random.Generator, lo: np.ndarray, n: int) -> np.ndarray:
    """Points over and around the map: random, on box corners and faces (ties), inside boxes."""
    pts = rng.uniform(-1.0, 7.0, size=(n, 3))
    k = rng.integers(0, len(lo), n // 4)
    pts[: n // 4] = lo[k] + rng.integers(0, 3, size=(n // 4, 3)) * 0.05
    return pts


@pytest.mark.parametrize("m", [1, 3, 50, 2000])
def test_index_queries_equal_brute_force(rng, m):
    lo, hi = _voxel_boxes(rng, m)
    index = BoxIndex(lo, hi)
    pts = _queries(rng, lo, 3000)
    assert np.array_equal(index.min_distance(pts), min_box_distance(pts, lo, hi))
    assert np.array_equal(index.inside_any(pts), inside_any_box(pts, lo, hi))
    cap = rng.uniform(0.0, 0.5, len(pts))
    assert np.array_equal(
        index.min_distance(pts, cap), np.minimum(cap, min_box_distance(pts, lo, hi))
    )
    p1 = pts + rng.normal(0.0, 1.5, pts.shape)
    p1[::5, rng.integers(0, 3)] = pts[::5, rng.integers(0, 3)]  # axis-parallel segments
    p1[::7] = pts[::7]  # points as segments
    assert np.array_equal(index.segments_blocked(pts, p1), segments_blocked(pts, p1, lo, hi))
    for r in (0.0, 0.05, 0.3):
        got = index.cones_blocked(pts[:800], p1[:800], r)
        assert np.array_equal(got, cones_blocked(pts[:800], p1[:800], lo, hi, r))
    radius = rng.uniform(0.0, 0.6, 40)
    near = index.near(pts[:40], radius)
    d = min_box_distance_all(pts[:40], lo, hi)
    assert set(np.flatnonzero((d <= radius[:, None]).any(axis=0))) <= set(near)
    # only rounding may add a box: every extra one is within 1e-6 of the radius
    extra = np.setdiff1d(near, np.flatnonzero((d <= radius[:, None]).any(axis=0)))
    assert np.all((d[:, extra] - radius[:, None]).min(axis=0) <= 1e-6) if len(extra) else True


@pytest.mark.parametrize("m", [1, 40, 2000])
def test_min_distance_along_grids_and_paths_equals_brute_force(rng, m):
    """Each point's search starts from the box nearest the point before it: along a raster grid,
    a path and its probes, with caps that hide that box now and then (so the start box is
    sometimes the answer, sometimes beaten, sometimes absent), the values stay the brute force's
    bit for bit."""
    lo, hi = _voxel_boxes(rng, m)
    index = BoxIndex(lo, hi)
    axes = [np.linspace(-0.5, 6.5, n) for n in (23, 19, 11)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    path = np.cumsum(rng.normal(0.0, 0.05, (2000, 3)), axis=0) + 3.0
    probes = np.concatenate([path + e for e in (0.0, 1e-3, -1e-3)])
    for pts in (grid, path, probes, grid[::-1]):
        want = min_box_distance(pts, lo, hi)
        assert np.array_equal(index.min_distance(pts), want)
        cap = np.where(rng.random(len(pts)) < 0.3, rng.uniform(-0.05, 0.3, len(pts)), np.inf)
        assert np.array_equal(index.min_distance(pts, cap), np.minimum(cap, want))
        assert np.array_equal(index.inside_any(pts), inside_any_box(pts, lo, hi))


@pytest.mark.parametrize("m", [1, 50, 2000])
def test_overlapping_boxes_equal_the_scan(rng, m):
    """overlapping(a, b) is the scan's sorted indices, ties (shared faces, zero-size query boxes)
    included; extended trees too; a misshapen corner raises."""
    lo, hi = _voxel_boxes(rng, m)
    index = BoxIndex(lo, hi).extended(lo[:7] + 0.05, hi[:7] + 0.05)
    all_lo, all_hi = index.lo, index.hi
    pts = _queries(rng, all_lo, 600)
    size = rng.uniform(0.0, 1.5, pts.shape) * (rng.random((len(pts), 1)) < 0.8)  # some points
    for a, b in zip(pts, pts + size, strict=True):
        want = np.flatnonzero(np.all((all_lo <= b) & (all_hi >= a), axis=1))
        np.testing.assert_array_equal(index.overlapping(a, b), want)
    with pytest.raises(GeometryError, match="overlapping"):
        index.overlapping(np.zeros(6), np.ones(3))
    assert len(BoxIndex(np.zeros((0, 3)), np.zeros((0, 3))).overlapping(pts[0], pts[0])) == 0


def test_empty_index(rng):
    index = BoxIndex(np.zeros((0, 3)), np.zeros((0, 3)))
    pts = rng.uniform(0, 1, (5, 3))
    assert np.all(np.isinf(index.min_distance(pts)))
    assert not index.segments_blocked(pts, pts + 1).any()
    assert not index.cones_blocked(pts, pts + 1, 0.2).any()
    assert len(index.near(pts, 10.0)) == 0


def test_extended_index_equals_a_fresh_one(rng):
    lo, hi = _voxel_boxes(rng, 500)
    index = BoxIndex(lo[:300], hi[:300])
    for s, e in ((300, 301), (301, 420), (420, len(lo))):
        index = index.extended(lo[s:e], hi[s:e])
    assert np.array_equal(index.lo, lo) and np.array_equal(index.hi, hi)
    pts = _queries(rng, lo, 2000)
    p1 = pts + rng.normal(0.0, 1.0, pts.shape)
    assert np.array_equal(index.min_distance(pts), min_box_distance(pts, lo, hi))
    assert np.array_equal(index.segments_blocked(pts, p1), segments_blocked(pts, p1, lo, hi))
    assert np.array_equal(index.cones_blocked(pts, p1, 0.2), cones_blocked(pts, p1, lo, hi, 0.2))
    assert BoxIndex.of(lo, hi) is index


def test_of_reuses_by_content(rng):
    lo, hi = _voxel_boxes(rng, 100)
    a = BoxIndex.of(lo, hi)
    assert BoxIndex.of(lo.copy(), hi.copy()) is a
    assert BoxIndex.of(lo + 0.5, hi + 0.5) is not a


def test_of_finds_an_index_by_its_own_arrays_and_extensions_by_content(rng, monkeypatch):
    lo, hi = _voxel_boxes(rng, 200)
    grown = BoxIndex.of(lo[:150], hi[:150]).extended(lo[150:], hi[150:])
    # an index's own arrays are not read again: no content hash of them
    monkeypatch.setattr(
        "secure3d.geometry.box_index._content_key", lambda *a: pytest.fail("hashed the boxes")
    )
    assert BoxIndex.of(grown.lo, grown.hi) is grown
    monkeypatch.undo()
    # equal boxes in other arrays find it by content (its key computed on that first need)
    assert BoxIndex.of(lo.copy(), hi.copy()) is grown
    assert BoxIndex.of(grown.lo, hi.copy()) is grown
    assert BoxIndex.of(lo[:150] + 0.1, hi[:150] + 0.1) is not grown


def test_degenerate_centres_build_a_shallow_tree():
    # many boxes with one centre (nested) and exponentially spaced ones: the build must not recurse
    # past the traversal stack
    k = np.arange(3000, dtype=float)
    lo = np.stack([-k, -k, -k], axis=1)
    hi = -lo
    lo2 = np.stack([2.0 ** (k[:60] / 2), np.zeros(60), np.zeros(60)], axis=1)
    lo, hi = np.concatenate([lo, lo2]), np.concatenate([hi, lo2 + 0.1])
    index = BoxIndex(lo, hi)
    pts = np.random.default_rng(1).uniform(-10, 10, (200, 3))
    assert np.array_equal(index.min_distance(pts), min_box_distance(pts, lo, hi))


def test_hull_screen_is_the_numpy_screen_bit_for_bit(rng):
    from secure3d.geometry._box_kernels import hull_screen

    lo, hi = _voxel_boxes(rng, 700)
    for P in (1, 6):
        pts = rng.uniform(-1.0, 7.0, size=(30, P, 3))
        pts[:5] = lo[:5, None, :]  # on box corners
        reach = rng.uniform(0.0, 1.0, 30)
        want = min_box_distance_all(pts.reshape(-1, 3), lo, hi).reshape(30, P, -1).min(axis=1)
        assert np.array_equal(hull_screen(pts, reach, lo, hi), want - reach[:, None])


@pytest.mark.parametrize("extend", [False, True])
def test_hull_near_returns_the_screen_entries_within_the_limit(rng, extend):
    """The index's walk yields exactly the hull_screen entries at most the limit, with their bits,
    row-major (also on an extended tree, and on box corners where distances tie)."""
    from secure3d.geometry._box_kernels import hull_screen
    from secure3d.geometry._hull_near_kernel import hull_near

    lo, hi = _voxel_boxes(rng, 1500)
    index = BoxIndex(lo[:1000], hi[:1000]).extended(lo[1000:], hi[1000:]) if extend else None
    index = index or BoxIndex(lo, hi)
    for P in (1, 6):
        pts = rng.uniform(-1.0, 7.0, size=(40, P, 3))
        pts[:8] = lo[:8, None, :] + 0.05  # on box faces and corners
        reach = rng.uniform(0.0, 1.0, 40)
        full = hull_screen(pts, reach, index.lo, index.hi)
        for limit in (-0.5, 0.0, 0.02, 0.4, 1.5):
            ks, js, vs = hull_near(pts, reach, limit, index.lo, index.hi, *index.tree)
            want = np.argwhere(full <= limit)
            assert np.array_equal(np.stack([ks, js], axis=1), want)
            assert np.array_equal(vs, full[want[:, 0], want[:, 1]])
    empty = BoxIndex(np.zeros((0, 3)), np.zeros((0, 3)))
    assert len(hull_near(pts, reach, 1.0, empty.lo, empty.hi, *empty.tree)[0]) == 0


def test_hull_nearest_returns_each_rows_smallest_entries(rng):
    """Per row, the n smallest hull_screen entries within the limit: their values exactly (boxes
    at equal entries may be any of them), each returned box holding the value given for it."""
    from secure3d.geometry._box_kernels import hull_screen
    from secure3d.geometry._hull_near_kernel import hull_nearest

    lo, hi = _voxel_boxes(rng, 1500)
    index = BoxIndex(lo, hi)
    pts = rng.uniform(-1.0, 7.0, size=(40, 6, 3))
    pts[:8] = lo[:8, None, :] + 0.05
    reach = rng.uniform(0.0, 1.0, 40)
    full = hull_screen(pts, reach, lo, hi)
    for n, limit in ((1, 0.3), (9, 0.3), (17, 1.5), (40, 0.05), (3, -2.0)):
        ks, js, vs = hull_nearest(pts, reach, limit, n, lo, hi, *index.tree)
        for k in range(40):
            row = full[k]
            want = np.sort(row[row <= limit])[:n]
            assert np.array_equal(vs[ks == k], want)
            assert np.array_equal(row[js[ks == k]], want)
            assert len(set(js[ks == k])) == len(want)


def test_clearance_is_the_nearer_of_the_boxes_and_the_bounds_faces():
    from secure3d.geometry.polytope import min_box_distance

    rng = np.random.default_rng(7)
    lo = rng.uniform(0.0, 4.0, (30, 3))
    hi = lo + rng.uniform(0.05, 1.0, (30, 3))
    p = rng.uniform(-0.5, 5.5, (200, 3))
    b_lo, b_hi = np.zeros(3), np.full(3, 5.0)
    faces = np.minimum(p - b_lo, b_hi - p)
    for dims in (3, 2):
        want = np.minimum(faces[:, :dims].min(axis=1), min_box_distance(p, lo, hi))
        got = BoxIndex(lo, hi).clearance(p, b_lo, b_hi, dims)
        np.testing.assert_allclose(got, want, atol=1e-12)
    empty = BoxIndex(np.zeros((0, 3)), np.zeros((0, 3)))
    np.testing.assert_array_equal(empty.clearance(p, b_lo, b_hi), faces.min(axis=1))


def test_clearance_refuses_malformed_bounds_by_name():
    index = BoxIndex(np.zeros((1, 3)), np.ones((1, 3)))
    with pytest.raises(GeometryError, match="clearance: bounds lo, hi must be 3-vectors"):
        index.clearance(np.zeros((2, 3)), np.zeros(2), np.ones(3))
    with pytest.raises(GeometryError, match="dims 1-3"):
        index.clearance(np.zeros((2, 3)), np.zeros(3), np.ones(3), dims=4)


@pytest.mark.parametrize("m", [0, 3, 400])
def test_fans_clear_is_any_candidate_with_every_segment_clear(rng, m):
    """fans_clear: row i is clear iff some listed origin reaches all of its tips with no segment
    blocked (the brute force over every (row, candidate, tip) segment), whatever the order."""
    lo, hi = _voxel_boxes(rng, max(m, 1))
    lo, hi = lo[:m], hi[:m]
    index = BoxIndex(lo, hi)
    origins = rng.uniform(-1.0, 7.0, (30, 3))
    tips = rng.uniform(-1.0, 7.0, (200, 7, 3))
    tips[::9] = origins[0]  # segments of zero length
    counts = rng.integers(0, 6, 200)
    counts[::11] = 0  # rows with no candidate: never clear
    indptr = np.concatenate([[0], np.cumsum(counts)])
    cols = rng.integers(0, 30, indptr[-1])
    want = np.zeros(200, bool)
    for i in range(200):
        for c in cols[indptr[i] : indptr[i + 1]]:
            p0 = np.repeat(origins[c][None], 7, axis=0)
            if not segments_blocked(p0, tips[i], lo, hi).any():
                want[i] = True
    got = index.fans_clear(origins, tips, indptr, cols)
    assert np.array_equal(got, want)
    assert 0 < want.sum() < 200 or m == 0
    flipped = np.concatenate(
        [cols[a:b][::-1] for a, b in zip(indptr[:-1], indptr[1:], strict=True)]
    )
    assert np.array_equal(index.fans_clear(origins, tips, indptr, flipped), want)


def test_fans_clear_refuses_malformed_rows_by_name(rng):
    lo, hi = _voxel_boxes(rng, 5)
    index = BoxIndex(lo, hi)
    o, tips = np.zeros((4, 3)), np.zeros((2, 7, 3))
    for args, what in (
        ((o, np.zeros((2, 7)), [0, 1, 2], [0, 1]), "tips"),
        ((o, np.full((2, 7, 3), np.nan), [0, 1, 2], [0, 1]), "tips"),
        ((o, tips, [0, 2], [0, 1]), "indptr"),
        ((o, tips, [0, 2, 1], [0, 1]), "indptr"),
        ((o, tips, [0, 1, 2], [0, 4]), "cols"),
    ):
        with pytest.raises(GeometryError, match=what):
            index.fans_clear(*args)
