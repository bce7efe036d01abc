"""A scan limited to a box updates exactly its unlimited updates' voxels that meet the box."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.errors import GeometryError
from secure3d.mapping import scan as scan_module
from secure3d.mapping.keys import box_keys, coords_to_keys, morton_decode, scan_update
from secure3d.mapping.occupancy import OccupancyMap
from secure3d.mapping.octomap_io import read_scan_dat
from secure3d.mapping.scan import scan_tiles


@pytest.fixture(scope="module")
def scan(octomap_dir) -> np.ndarray:
    return read_scan_dat(octomap_dir / "scan.dat.bz2")


def _in_keys(codes: np.ndarray, keep: np.ndarray) -> np.ndarray:
    keys = morton_decode(codes)
    return np.all((keys >= keep[0]) & (keys <= keep[1]), axis=1)


def _assert_limited(full, boxed, keep) -> int:
    """``boxed`` is ``full`` less the voxels outside the key box; returns how many were left out."""
    want_free = np.sort(full.free[_in_keys(full.free, keep)])
    np.testing.assert_array_equal(np.sort(boxed.free), want_free)
    np.testing.assert_array_equal(boxed.occupied, full.occupied[_in_keys(full.occupied, keep)])
    assert tuple(boxed[2:]) == tuple(full[2:]), "the rays are counted as without the box"
    return full.free.size + full.occupied.size - boxed.free.size - boxed.occupied.size


# boxes round the origin (0.1, -0.2, 0.3): tight ones cut most rays, one holds the whole scan, and
# two lie beside the origin (their rays enter them from outside)
BOXES = [
    ([-2.0, -1.5, -0.4], [3.0, 1.0, 1.1]),
    ([0.0, -0.3, 0.2], [0.25, 0.0, 0.35]),
    ([-100.0, -100.0, -100.0], [100.0, 100.0, 100.0]),
    ([1.0, -3.0, -1.0], [4.0, 3.0, 2.0]),
    ([-6.0, 2.0, -3.0], [6.0, 5.0, 0.0]),
]


@pytest.mark.parametrize("box", BOXES)
@pytest.mark.parametrize(
    "resolution, max_range, clear_range", [(0.1, 6.0, 4.0), (0.05, None, None)]
)
def test_a_boxed_scan_is_the_scan_less_the_voxels_outside(
    scan, box, resolution, max_range, clear_range
):
    o = np.array([0.1, -0.2, 0.3])
    full = scan_update(scan, o, resolution, max_range, clear_range=clear_range)
    boxed = scan_update(scan, o, resolution, max_range, clear_range=clear_range, box=box)
    left_out = _assert_limited(full, boxed, box_keys(box, resolution))
    if box is not BOXES[2]:
        assert left_out > 1000, "the box must leave part of the scan out"
    else:
        assert left_out == 0


@pytest.mark.parametrize("box", [BOXES[0], BOXES[3]])
def test_every_kernel_limits_alike(scan, box, monkeypatch):
    """Threads, the chunked kernel (scans too big for dense bitmaps) and OctoMap's discretised
    update all leave out exactly the voxels outside the box."""
    o = np.array([0.1, -0.2, 0.3])
    keep = box_keys(box, 0.1)
    monkeypatch.setenv("SECURE3D_SCAN_THREADS", "3")
    monkeypatch.setattr(scan_module, "_RAYS_PER_PART", 1000)
    assert scan_module._trace_parts(len(scan)) == 3
    _assert_limited(scan_update(scan, o, 0.1, 6.0), scan_update(scan, o, 0.1, 6.0, box=box), keep)
    _assert_limited(
        scan_update(scan, o, 0.1, 6.0, discretize=True),
        scan_update(scan, o, 0.1, 6.0, discretize=True, box=box),
        keep,
    )
    monkeypatch.setattr(scan_module, "_DENSE_VOXEL_LIMIT", 0)  # every scan takes the chunked kernel
    _assert_limited(scan_update(scan, o, 0.1, 6.0), scan_update(scan, o, 0.1, 6.0, box=box), keep)


def test_box_keys_are_the_voxels_meeting_the_box():
    keep = box_keys([[0.0, -0.25, 1.0], [0.5, 0.25, 1.01]], 0.1)
    lo, _ = coords_to_keys(np.array([[0.05, -0.25, 1.05]]), 0.1)
    hi, _ = coords_to_keys(np.array([[0.55, 0.25, 1.05]]), 0.1)
    np.testing.assert_array_equal(keep, np.concatenate([lo, hi]))
    # a box beyond the key range holds every key up to the range's end
    big = box_keys([[-1e9, 0.0, 0.0], [1e9, 1.0, 1.0]], 0.1)
    assert big[0, 0] == 0 and big[1, 0] == 2**16 - 1


@pytest.mark.parametrize(
    "box, match",
    [
        ([[0.0, 0.0, 0.0]], "two finite corners"),
        ([[0.0, 0.0, np.nan], [1.0, 1.0, 1.0]], "two finite corners"),
        ([[0.0, 2.0, 0.0], [1.0, 1.0, 1.0]], "lo .* must not exceed hi"),
        ("room", "two corners"),
    ],
)
def test_a_bad_box_is_refused_by_name(box, match):
    with pytest.raises(GeometryError, match=f"box: .*{match}"):
        scan_tiles(np.ones((3, 3)), np.zeros(3), 0.1, box=box)


def test_a_depth_image_inserted_in_a_box_leaves_the_rest_unknown():
    """OccupancyMap.insert_depth_image with a box: inside it the map is what it is without the box;
    outside it nothing is known."""
    h, w = 48, 64
    depth = np.full((h, w), np.inf)
    depth[10:30, 20:50] = 3.0  # a wall patch; the rest sees nothing up to the range
    K = (32.0, 32.0, 31.5, 23.5)
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # looking along +x
    o = np.array([0.05, 0.05, 1.0])
    box = ([-0.5, -1.0, 0.0], [2.5, 1.0, 2.0])
    maps = [OccupancyMap(0.1), OccupancyMap(0.1)]
    for m, b in zip(maps, (None, box), strict=True):
        m.insert_depth_image(depth, K, R, o, 5.0, far_kind="depth", box=b)
    g = np.stack(np.meshgrid(*[np.arange(-3.95, 6.0, 0.1)] * 3, indexing="ij"), -1).reshape(-1, 3)
    keep = box_keys(box, 0.1)  # the voxels that meet the box, some of their centres outside it
    keys, _ = coords_to_keys(g, 0.1)
    inside = np.all((keys >= keep[0]) & (keys <= keep[1]), axis=1)
    full, boxed = maps[0].classify(g), maps[1].classify(g)
    np.testing.assert_array_equal(boxed[inside], full[inside])
    assert np.all(boxed[~inside] == -1) and np.count_nonzero(full[~inside] >= 0) > 1000
    assert np.count_nonzero(full[~inside] == 1) > 0, "the wall lies partly outside the box"


def test_tiles_in_box_refuses_a_bad_key_box():
    from secure3d.mapping.morton import tiles_in_box

    empty = (np.zeros(0, np.int64), np.zeros(0, np.uint64), np.zeros(0, np.int64))
    with pytest.raises(GeometryError, match="tiles_in_box: keep"):
        tiles_in_box(*empty, np.zeros((2, 3)))  # floats: metres, not keys
    with pytest.raises(GeometryError, match="tiles_in_box: keep"):
        tiles_in_box(*empty, np.zeros(3, np.int64))
    assert all(len(a) == 0 for a in tiles_in_box(*empty, np.zeros((2, 3), np.int64)))
