"""A scan that clears space only within a free range: the same hits, and free voxels that are the
OctoMap rule's cut short, none beyond the range (a distance, or a depth along an axis)."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.errors import GeometryError
from secure3d.mapping.keys import box_keys, coords_to_keys, morton_decode, morton_encode
from secure3d.mapping.morton import TREE_MAX_VAL
from secure3d.mapping.occupancy import OccupancyMap
from secure3d.mapping.octomap_io import read_scan_dat
from secure3d.mapping.scan import scan_tiles
from secure3d.mapping.scan_range import scan_tiles_free_range

# off every voxel boundary: a ray from a boundary can run along voxel edges, where the walk's
# choice between two voxels flips with the last bit of its end point
ORIGIN = np.array([0.137, -0.213, 0.311])


@pytest.fixture(scope="module")
def scan(octomap_dir) -> np.ndarray:
    return read_scan_dat(octomap_dir / "scan.dat.bz2")


def _centres(codes: np.ndarray, res: float) -> np.ndarray:
    return (morton_decode(codes) - TREE_MAX_VAL + 0.5) * res


def _cut_end_codes(points, origin, res, own_length, free) -> np.ndarray:
    """Codes of the voxels where rays longer than ``free`` (of their clearing length) stop."""
    d = points - origin
    length = np.linalg.norm(d, axis=1)
    cut = (own_length > free) & np.isfinite(length)
    ends = origin + d[cut] / length[cut, None] * free
    return morton_encode(coords_to_keys(ends, res)[0])


@pytest.mark.parametrize(
    "res, max_range, clear_range, free", [(0.1, 6.0, 4.0, 2.5), (0.05, None, None, 3.0)]
)
def test_the_free_range_cuts_the_octomap_rules_free_space_and_keeps_every_hit(
    scan, res, max_range, clear_range, free
):
    full = scan_tiles(scan, ORIGIN, res, max_range, clear_range=clear_range)
    cut = scan_tiles_free_range(scan, ORIGIN, res, max_range, free, clear_range=clear_range)
    np.testing.assert_array_equal(np.sort(cut.occupied), np.sort(full.occupied))
    assert tuple(cut[3:]) == tuple(full[3:]), "the rays are counted as without the free range"
    got, everything = cut.free(), full.free()
    assert np.isin(got, everything).all(), "it clears only what the OctoMap rule clears"
    dist = np.linalg.norm(_centres(got, res) - ORIGIN, axis=1)
    assert dist.max() <= free + 0.5 * np.sqrt(3) * res + 1e-6
    assert np.linalg.norm(_centres(everything, res) - ORIGIN, axis=1).max() > free + 1.0
    # the OctoMap rule with the free range as its range (a beam clipped there clears up to it),
    # less the hits: the same, but for the voxels where a cut ray stops (never cleared here)
    cr = max_range if clear_range is None else clear_range
    ref = scan_tiles(scan, ORIGIN, res, free, clear_range=free if cr is None else min(cr, free))
    want = np.setdiff1d(ref.free(), full.occupied)
    length = np.linalg.norm(scan - ORIGIN, axis=1)
    own = length if max_range is None else np.where(length > max_range, cr, length)
    stops = _cut_end_codes(scan, ORIGIN, res, own, free)
    assert np.isin(got, want).all()
    missing = np.setdiff1d(want, got)
    assert np.isin(missing, stops).all(), "only the voxels where cut rays stop are left out"
    assert len(got) > 0.9 * len(want)


def test_a_free_range_at_or_beyond_the_sensor_range_changes_nothing(scan):
    full = scan_tiles(scan, ORIGIN, 0.1, 5.0, clear_range=4.0)
    same = scan_tiles_free_range(scan, ORIGIN, 0.1, 5.0, 5.0, clear_range=4.0)
    np.testing.assert_array_equal(np.sort(same.free()), np.sort(full.free()))
    np.testing.assert_array_equal(same.occupied, full.occupied)


def test_a_free_depth_along_an_axis_bounds_the_depth_of_what_is_cleared(scan):
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    res, free = 0.1, 2.0
    full = scan_tiles(scan, ORIGIN, res, None)
    cut = scan_tiles_free_range(scan, ORIGIN, res, None, free, free_axis=axis)
    np.testing.assert_array_equal(np.sort(cut.occupied), np.sort(full.occupied))
    got = cut.free()
    assert np.isin(got, full.free()).all()
    depth = (_centres(got, res) - ORIGIN) @ axis
    assert depth.max() <= free + 0.5 * np.sqrt(3) * res + 1e-6
    # a depth limit reaches farther off the axis than the same distance limit does
    dist = np.linalg.norm(_centres(got, res) - ORIGIN, axis=1)
    assert dist.max() > free + 0.5
    # rays that go backwards along the axis clear nothing
    assert depth.min() >= -0.5 * np.sqrt(3) * res - 1e-6


def test_a_discretised_scan_with_a_box_keeps_every_hit_and_clears_less(scan):
    box = ([-2.0, -1.5, -0.4], [3.0, 1.0, 1.1])
    full = scan_tiles(scan, ORIGIN, 0.1, 6.0, True, box=box)
    cut = scan_tiles_free_range(scan, ORIGIN, 0.1, 6.0, 1.5, True, box=box)
    np.testing.assert_array_equal(np.sort(cut.occupied), np.sort(full.occupied))
    assert tuple(cut[3:]) == tuple(full[3:])
    got = cut.free()
    assert 0 < len(got) < len(full.free()) and np.isin(got, full.free()).all()
    keys = morton_decode(got)
    keep = box_keys(box, 0.1)
    assert np.all((keys >= keep[0]) & (keys <= keep[1]))


@pytest.mark.parametrize(
    "free, axis, match",
    [
        (-1.0, None, "free_range"),
        (float("nan"), None, "free_range"),
        ("far", None, "free_range"),
        (2.0, [1.0, 1.0, 0.0], "free_axis"),
        (2.0, [0.0, 1.0], "free_axis"),
    ],
)
def test_bad_free_ranges_and_axes_are_refused_by_name(scan, free, axis, match):
    with pytest.raises(GeometryError, match=match):
        scan_tiles_free_range(scan[:10], ORIGIN, 0.1, 5.0, free, free_axis=axis)


def test_a_depth_image_clears_space_within_its_free_depth():
    """A camera looking along +x at a wall 5 m away, free depth 2 m (as the closed loop inserts
    frames): the wall's hits all count, and nothing beyond 2 m (plus a voxel) is cleared."""
    from secure3d.mapping.depth import optical_axis

    h, w, f = 30, 40, 20.0
    depth = np.full((h, w), 5.0)
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    o = np.zeros(3)
    a, b = OccupancyMap(0.1), OccupancyMap(0.1)
    sa = a.insert_depth_image(depth, (f, f, w / 2, h / 2), R, o, 6.0, far_kind="depth")
    sb = b.insert_depth_image(
        depth, (f, f, w / 2, h / 2), R, o, 6.0, far_kind="depth", free_range=2.0
    )
    np.testing.assert_array_equal(np.sort(sb.occupied_codes), np.sort(sa.occupied_codes))
    np.testing.assert_array_equal(optical_axis(R), [1.0, 0.0, 0.0])
    free = b.free_voxels()
    assert free[:, 0].max() <= 2.0 + 0.1 and a.free_voxels()[:, 0].max() > 4.5
    assert np.linalg.norm(free, axis=1).max() > 2.5, "off the axis a depth limit reaches farther"
    with pytest.raises(GeometryError, match="cam2world"):
        optical_axis(np.zeros((3, 3)))
