"""Trust layers: the paper's map update rules (proof of the safety theorem), one test per rule.

C_free <- C_free u (observed \\ O);   C_obst <- (C_obst u O) \\ (observed n C_free).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from secure3d.errors import ConfigError, GeometryError
from secure3d.mapping import OccupancyMap, Trust
from secure3d.mapping.keys import coords_to_codes
from secure3d.mapping.occupancy import BOUNDARY_TOUCH

RES = 0.1


def wall_scan(x: float, half_width: float = 0.6) -> np.ndarray:
    """End points of a dense scan of the wall x = const seen from the origin."""
    y, z = np.meshgrid(np.arange(-half_width, half_width, 0.02), np.arange(-0.3, 0.3, 0.02))
    return np.stack([np.full(y.size, x), y.ravel(), z.ravel()], axis=1)


def centre(p) -> np.ndarray:
    """Centre of the voxel containing p."""
    return (np.floor(np.asarray(p, float) / RES) + 0.5) * RES


def test_sensed_free_overrides_claimed_occupied():
    """C_obst <- ... \\ (observed n C_free): a hidden-corridor attack cannot block a seen path."""
    m = OccupancyMap(RES)
    phantom = centre([1.0, 0.0, 0.0])
    m.set_claim_voxels(phantom[None], occupied=True)
    assert m.trust(phantom[None])[0] == Trust.CLAIMED_OCCUPIED
    assert m.is_known_obstacle(phantom[None])[0]
    m.insert_point_cloud(wall_scan(2.0), np.zeros(3))
    assert m.classify(phantom[None])[0] == 0, "the beams to the wall passed through it"
    assert m.trust(phantom[None])[0] == Trust.SENSED_FREE
    assert not m.is_known_obstacle(phantom[None])[0]
    known = m.known_obstacle_voxels()
    assert not np.any(np.all(np.isclose(known, phantom), axis=1))


def test_sensed_occupied_overrides_claimed_free():
    """C_obst <- C_obst u O: an obstacle the server deleted is an obstacle once seen."""
    m = OccupancyMap(RES)
    m.set_claim_boxes([[-1.0, -1.0, -1.0]], [[3.0, 1.0, 1.0]], occupied=False)
    hidden = centre([2.0, 0.0, 0.0])
    assert m.trust(hidden[None])[0] == Trust.CLAIMED_FREE
    m.insert_point_cloud(wall_scan(2.0), np.zeros(3))
    assert m.trust(hidden[None])[0] == Trust.SENSED_OCCUPIED
    assert m.is_known_obstacle(hidden[None])[0]
    known = m.known_obstacle_voxels()
    assert np.any(np.all(np.isclose(known, hidden), axis=1))


def test_unobserved_claims_are_kept():
    """Voxels outside every observation keep the server's claim, occupied or free."""
    m = OccupancyMap(RES)
    behind_occ = centre([-2.0, 0.0, 0.0])
    behind_free = centre([-2.0, 1.0, 0.0])
    m.set_claim_voxels(np.stack([behind_occ, behind_free]), occupied=np.array([True, False]))
    m.insert_point_cloud(wall_scan(2.0), np.zeros(3))
    assert not m.observed(np.stack([behind_occ, behind_free])).any()
    np.testing.assert_array_equal(
        m.trust(np.stack([behind_occ, behind_free])), [Trust.CLAIMED_OCCUPIED, Trust.CLAIMED_FREE]
    )
    assert m.is_known_obstacle(behind_occ[None])[0]
    assert not m.is_known_obstacle(behind_free[None])[0]


def test_outside_bounds_is_not_plannable():
    m = OccupancyMap(RES, bounds=([0.0, -1.0, -1.0], [4.0, 1.0, 2.0]))
    inside, outside = np.array([[2.0, 0.0, 0.0]]), np.array([[5.0, 0.0, 0.0]])
    assert m.in_bounds(inside)[0] and not m.in_bounds(outside)[0]
    assert not m.is_known_obstacle(inside)[0]
    assert m.is_known_obstacle(outside)[0], "unknown space outside bounds is an obstacle"
    m.insert_point_cloud(wall_scan(6.0), np.array([1.0, 0.0, 0.0]))
    assert m.trust(outside)[0] == Trust.SENSED_FREE
    assert m.is_known_obstacle(outside)[0], "even sensed free space outside bounds"
    lo, hi = m.known_obstacle_boxes()
    covered = np.all((outside >= lo) & (outside <= hi), axis=1)
    assert covered.any(), "the bounds' walls reach the planner as boxes"
    lo_in, hi_in = m.known_obstacle_boxes(include_bounds=False)
    assert not np.all((outside >= lo_in) & (outside <= hi_in), axis=1).any()


def test_known_obstacles_formula_against_brute_force(rng):
    """Known = sensed occupied u (claimed occupied \\ sensed free), on a random mix."""
    m = OccupancyMap(RES)
    m.insert_point_cloud(rng.uniform(-1, 1, size=(300, 3)), np.zeros(3))
    region = (np.stack(np.meshgrid(*[np.arange(-12, 12)] * 3, indexing="ij"), -1).reshape(-1, 3)
              + 0.5) * RES  # fmt: skip
    claimed = rng.random(region.shape[0]) < 0.3
    m.set_claim_voxels(region[claimed], occupied=True)
    labels = m.classify(region)
    expected = (labels == 1) | (claimed & (labels == -1))
    known = m.known_obstacle_voxels()
    in_region = np.all(np.abs(known) < 1.2, axis=1)
    got = {tuple(c) for c in np.round(known[in_region], 6)}
    assert got == {tuple(c) for c in np.round(region[expected], 6)}
    np.testing.assert_array_equal(m.is_known_obstacle(region), expected)
    trust = m.trust(region)
    np.testing.assert_array_equal(
        expected, (trust == Trust.SENSED_OCCUPIED) | (trust == Trust.CLAIMED_OCCUPIED)
    )
    assert set(np.unique(trust)) == {int(t) for t in Trust} - {int(Trust.CLAIMED_FREE)}
    # voxels with sensor evidence, by code: the same answer without the claim layer
    codes, _ = coords_to_codes(region, RES)
    sensed = labels >= 0
    assert sensed.sum() > 20 and (claimed & sensed & (labels == 0)).any()
    np.testing.assert_array_equal(m.is_known_obstacle_sensed(codes[sensed]), expected[sensed])
    with pytest.raises(GeometryError, match="no sensor evidence"):
        m.is_known_obstacle_sensed(codes[~sensed][:3])
    # the known obstacles with their trust, as known_obstacle_voxels and trust give them
    centres, kinds = m.known_obstacles()
    assert sorted(map(tuple, np.round(centres, 6))) == sorted(map(tuple, np.round(known, 6)))
    np.testing.assert_array_equal(kinds, m.trust(centres))
    assert set(np.unique(kinds)) == {int(Trust.SENSED_OCCUPIED), int(Trust.CLAIMED_OCCUPIED)}


def test_every_trust_level_and_observed():
    m = OccupancyMap(RES)
    pts = np.array([[5.0, 5.0, 5.0], [6.0, 5.0, 5.0], [7.0, 5.0, 5.0], [0.5, 0, 0], [2.0, 0, 0]])
    m.set_claim_voxels(pts[1:2], occupied=False)
    m.set_claim_voxels(pts[2:3], occupied=True)
    m.insert_point_cloud(wall_scan(2.0), np.zeros(3))
    np.testing.assert_array_equal(
        m.trust(pts),
        [
            Trust.UNKNOWN,
            Trust.CLAIMED_FREE,
            Trust.CLAIMED_OCCUPIED,
            Trust.SENSED_FREE,
            Trust.SENSED_OCCUPIED,
        ],
    )
    np.testing.assert_array_equal(m.observed(pts), [False, False, False, True, True])
    assert m.trust([[np.nan, 0, 0]])[0] == Trust.UNKNOWN


def test_claim_boxes_are_conservative(rng):
    """Occupied claims cover every voxel the box overlaps or touches; free claims only voxels inside it."""
    lo = np.array([[0.03, -0.21, 0.1]])
    hi = np.array([[0.47, 0.2, 0.31]])
    occ = OccupancyMap(RES)
    occ.set_claim_boxes(lo, hi, occupied=True)
    free = OccupancyMap(RES)
    free.set_claim_boxes(lo, hi, occupied=False)
    grid = (np.stack(np.meshgrid(*[np.arange(-8, 8)] * 3, indexing="ij"), -1).reshape(-1, 3)
            + 0.5) * RES  # fmt: skip
    vlo, vhi = grid - RES / 2, grid + RES / 2
    touch = BOUNDARY_TOUCH * RES
    overlaps = np.all((vlo < hi + touch) & (vhi > lo - touch), axis=1)
    contained = np.all((vlo >= lo - 1e-12) & (vhi <= hi + 1e-12), axis=1)
    np.testing.assert_array_equal(occ.trust(grid) == Trust.CLAIMED_OCCUPIED, overlaps)
    np.testing.assert_array_equal(free.trust(grid) == Trust.CLAIMED_FREE, contained)
    assert contained.sum() > 0 and overlaps.sum() > contained.sum()
    with pytest.raises(GeometryError, match="lo <= hi"):
        occ.set_claim_boxes(hi, lo)


def test_later_claims_override_earlier_and_clear():
    m = OccupancyMap(RES)
    m.set_claim_boxes([[0, 0, 0]], [[1, 1, 1]], occupied=True)
    m.set_claim_boxes([[0, 0, 0]], [[0.5, 0.5, 0.5]], occupied=False)
    assert m.trust([[0.25, 0.25, 0.25]])[0] == Trust.CLAIMED_FREE
    assert m.trust([[0.75, 0.75, 0.75]])[0] == Trust.CLAIMED_OCCUPIED
    m.clear_claim()
    assert m.trust([[0.75, 0.75, 0.75]])[0] == Trust.UNKNOWN
    with pytest.raises(GeometryError, match="non-finite"):
        m.set_claim_voxels([[np.nan, 0, 0]])


def test_claim_mesh_matches_the_solid():
    """A closed mesh claims exactly the voxels the solid touches (occupied) / contains (free)."""
    box = trimesh.creation.box(extents=[0.43, 0.62, 0.35])
    box.apply_transform(trimesh.transformations.rotation_matrix(0.4, [0, 0, 1]))
    box.apply_translation([0.51, -0.13, 0.22])
    occ = OccupancyMap(RES)
    occ.set_claim_mesh(box.vertices, box.faces, occupied=True)
    free = OccupancyMap(RES)
    free.set_claim_mesh(box.vertices, box.faces, occupied=False)
    grid = (np.stack(np.meshgrid(*[np.arange(-6, 14)] * 3, indexing="ij"), -1).reshape(-1, 3)
            + 0.5) * RES  # fmt: skip
    # Reference: sample each voxel densely and ask trimesh's exact half-space test (convex box).
    offsets = (np.stack(np.meshgrid(*[np.linspace(-0.5, 0.5, 5)] * 3), -1).reshape(-1, 3)) * RES
    samples = grid[:, None, :] + offsets[None]
    normals = box.facets_normal
    origins = np.array([box.vertices[box.faces[f[0]][0]] for f in box.facets])
    signed = np.einsum("vsd,fd->vsf", samples, normals) - np.einsum("fd,fd->f", origins, normals)
    inside = np.all(signed <= 1e-9, axis=2)
    touches, contained = inside.any(axis=1), inside.all(axis=1)
    got_occ = occ.trust(grid) == Trust.CLAIMED_OCCUPIED
    got_free = free.trust(grid) == Trust.CLAIMED_FREE
    assert np.all(got_occ[touches]), "an occupied claim must cover every voxel the solid touches"
    assert np.all(contained[got_free]), "a free claim must only cover voxels inside the solid"
    assert got_free.sum() > 0
    # Conservative but not wasteful: only voxels near the surface are added/dropped.
    assert got_occ.sum() <= 1.6 * touches.sum() and got_free.sum() >= 0.3 * contained.sum()


def test_claim_from_map_and_resolution_mismatch():
    server = OccupancyMap(RES)
    server.insert_point_cloud(wall_scan(1.5), np.zeros(3))
    m = OccupancyMap(RES)
    m.set_claim_from_map(server)
    np.testing.assert_allclose(
        np.sort(m.claimed_voxels(True), axis=0), np.sort(server.occupied_voxels(), axis=0)
    )
    np.testing.assert_allclose(
        np.sort(m.claimed_voxels(False), axis=0), np.sort(server.free_voxels(), axis=0)
    )
    assert m.observed(server.occupied_voxels()).sum() == 0, "a claim is not an observation"
    with pytest.raises(ConfigError, match="resolution"):
        OccupancyMap(0.2).set_claim_from_map(server)
