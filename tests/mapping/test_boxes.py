"""Planner views: greedy box merging, box budgets and corridor selection."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.errors import GeometryError
from secure3d.mapping import OccupancyMap
from secure3d.mapping.boxes import (
    box_point_distance,
    boxes_near_points,
    merge_cells,
    merge_cells_budget,
)


def box_cells(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Every cell of inclusive integer boxes (test-side reference, one box at a time)."""
    out = []
    for l, h in zip(lo, hi, strict=True):
        axes = [np.arange(a, b + 1) for a, b in zip(l, h, strict=True)]
        out.append(np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3))
    return np.concatenate(out) if out else np.empty((0, 3), np.int64)


def as_set(cells: np.ndarray) -> set:
    return {tuple(c) for c in cells.tolist()}


@pytest.mark.parametrize("density", [0.05, 0.3, 0.9])
def test_merge_is_an_exact_disjoint_cover(rng, density):
    grid = np.stack(np.meshgrid(*[np.arange(20)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = grid[rng.random(grid.shape[0]) < density] + np.array([30000, 40000, 32768])
    lo, hi = merge_cells(cells)
    covered = box_cells(lo, hi)
    assert covered.shape[0] == cells.shape[0], "boxes overlap or cover extra cells"
    assert as_set(covered) == as_set(cells)
    assert lo.shape[0] <= cells.shape[0]
    if density == 0.9:
        assert lo.shape[0] < 0.5 * cells.shape[0], "dense sets merge into far fewer boxes"


def test_merge_handles_several_blocks_and_solid_boxes():
    a = box_cells(np.array([[0, 0, 0]]), np.array([[9, 4, 2]]))
    b = box_cells(np.array([[600, 0, 0]]), np.array([[600, 300, 0]]))  # spans two blocks in y
    lo, hi = merge_cells(np.concatenate([a, b]))
    assert as_set(box_cells(lo, hi)) == as_set(np.concatenate([a, b]))
    assert lo.shape[0] == 3, "one box for the solid, one per block for the long bar"


def test_budget_gives_a_superset_within_budget(rng):
    cells = rng.integers(0, 64, size=(3000, 3))
    cells = np.unique(cells, axis=0)
    exact_lo, _ = merge_cells(cells)
    lo, hi = merge_cells_budget(cells, max_boxes=200)
    assert lo.shape[0] <= 200 < exact_lo.shape[0]
    inside = np.zeros(cells.shape[0], bool)
    for l, h in zip(lo, hi, strict=True):
        inside |= np.all((cells >= l) & (cells <= h), axis=1)
    assert inside.all(), "coarsening must never drop an obstacle cell"
    with pytest.raises(GeometryError, match="max_boxes"):
        merge_cells_budget(cells, 0)


def test_boxes_near_matches_brute_force(rng):
    lo = rng.uniform(-10, 10, size=(500, 3))
    hi = lo + rng.uniform(0.05, 2.0, size=(500, 3))
    pts = rng.uniform(-10, 10, size=(40, 3))
    for radius in (0.0, 0.5, 2.0):
        brute = np.array(
            [min(np.linalg.norm(np.maximum(np.maximum(l - p, p - h), 0)) for p in pts)
             for l, h in zip(lo, hi, strict=True)]
        ) <= radius  # fmt: skip
        np.testing.assert_array_equal(boxes_near_points(lo, hi, pts, radius), brute)
    d = box_point_distance(lo[:3], hi[:3], (lo[:3] + hi[:3]) / 2)
    np.testing.assert_allclose(np.diag(d), 0.0, atol=0, err_msg="centres are inside")


def test_known_obstacle_boxes_cover_exactly_the_known_voxels(rng):
    m = OccupancyMap(0.1)
    m.insert_point_cloud(rng.uniform(-2, 2, size=(2000, 3)), np.zeros(3))
    m.set_claim_boxes([[3.0, 3.0, 0.0]], [[4.0, 3.5, 1.0]])
    lo, hi = m.known_obstacle_boxes(include_bounds=False)
    centres = m.known_obstacle_voxels()
    inside = (centres[:, None, :] > lo[None]) & (centres[:, None, :] < hi[None])
    counts = np.all(inside, axis=2).sum(axis=1)
    np.testing.assert_array_equal(counts, 1, err_msg="each known voxel in exactly one box")
    volume = float(np.prod(hi - lo, axis=1).sum())
    assert volume == pytest.approx(centres.shape[0] * 0.1**3, rel=1e-9), "boxes cover nothing else"
    # Cached until the map changes.
    lo2, _ = m.known_obstacle_boxes(include_bounds=False)
    np.testing.assert_array_equal(lo, lo2)
    m.set_claim_boxes([[5.0, 5.0, 5.0]], [[5.2, 5.2, 5.2]])
    assert m.known_obstacle_boxes(include_bounds=False)[0].shape[0] > lo.shape[0]


def test_boxes_near_a_corridor():
    m = OccupancyMap(0.1, bounds=([-1, -1, -1], [10, 1, 2]))
    m.set_claim_boxes([[2.0, 0.5, 0.0], [6.0, -0.9, 0.0]], [[2.5, 0.8, 1.0], [6.5, -0.6, 1.0]])
    corridor = np.stack([np.linspace(0, 3, 10), np.zeros(10), np.full(10, 0.5)], axis=1)
    lo, hi = m.boxes_near(corridor, radius=0.6)
    # occupied claims also take the voxels their faces touch (faces on voxel boundaries here)
    assert np.any(np.all(np.isclose(lo[:, :2], [1.9, 0.4]), axis=1)), "the first obstacle is near"
    assert not np.any(lo[:, 0] >= 5.9 - 1e-9), "the far obstacle is not"
    assert lo.shape[0] == 1, "the bounds walls are farther than 0.6 m"
    lo, _ = m.boxes_near(corridor, radius=1.1)
    assert lo.shape[0] > 1, "with a larger radius the side walls of the bounds appear"
    with pytest.raises(GeometryError, match="radius"):
        m.boxes_near(corridor, -1.0)


def test_merge_grid_equals_merge_cells_across_blocks(rng):
    """Boxes read off a dense grid are merge_cells' boxes, in its order, also where the grid
    straddles the merge's block boundaries."""
    from secure3d.mapping.boxes import BLOCK_EDGE, merge_grid

    for trial in range(40):
        shape = tuple(int(v) for v in rng.integers(1, 40, 3))
        origin = rng.integers(BLOCK_EDGE - 30, BLOCK_EDGE + 5, 3) + (trial % 3) * 128 * BLOCK_EDGE
        grid = rng.random(shape) < rng.uniform(0.0, 0.9)
        lo, hi = merge_grid(grid, origin)
        ref_lo, ref_hi = merge_cells(np.argwhere(grid) + origin)
        np.testing.assert_array_equal(lo, ref_lo)
        np.testing.assert_array_equal(hi, ref_hi)
    with pytest.raises(GeometryError, match="origin"):
        merge_grid(np.ones((2, 2, 2), bool), [0.5, 0, 0])


def test_packed_closed_boxes_equal_the_dense_closing_and_merge(rng):
    """The bit-packed closing and merge give merge_grid(closed_grid(...))'s boxes in its order:
    radii 1-3, sparse to dense sets, rows of several 64-cell words, grids straddling the merge's
    block boundaries, and the sparse closing's fill too."""
    from secure3d.mapping._packed_closing import packed_closed_boxes
    from secure3d.mapping.boxes import BLOCK_EDGE, merge_grid
    from secure3d.mapping.keys import morton_encode
    from secure3d.mapping.obstacle_boxes import closed_grid

    for trial in range(60):
        high = 150 if trial % 4 == 0 else 40
        shape = tuple(int(v) for v in rng.integers(1, high, 3))
        grid = rng.random(shape) < rng.choice([0.002, 0.01, 0.05, 0.3, 0.7, 0.95])
        grid[tuple(rng.integers(0, shape))] = True
        origin = rng.integers(BLOCK_EDGE - 80, BLOCK_EDGE + 5, 3) + (trial % 2) * 127 * BLOCK_EDGE
        keys = np.argwhere(grid) + origin
        for radius in (1, 2, 3):
            ref_lo, ref_hi = merge_grid(*closed_grid(keys, radius))
            lo, hi = packed_closed_boxes(morton_encode(keys), radius)
            np.testing.assert_array_equal(lo, ref_lo)
            np.testing.assert_array_equal(hi, ref_hi)
