"""python-fcl collision world, cross-checked against exact box geometry computed with numpy."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from secure3d.errors import GeometryError
from secure3d.simulation.collision import CollisionWorld, rotation_z_to
from secure3d.simulation.scene import VOXEL_NAME, merged_voxel_boxes, voxel_boxes_from_centres
from secure3d.world.spec import Box, MeshObstacle


def box_sdf(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Exact signed distance from points (n, 3) to boxes (m, 3) -> (n, m); negative inside."""
    c, h = 0.5 * (lo + hi), 0.5 * (hi - lo)
    q = np.abs(points[:, None, :] - c[None]) - h[None]
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(axis=-1), 0.0)
    return outside + inside


def random_boxes(rng, n=8):
    lo = rng.uniform(-4, 4, (n, 3))
    hi = lo + rng.uniform(0.2, 1.5, (n, 3))
    return [Box(f"box{i}", tuple(lo[i]), tuple(hi[i])) for i in range(n)], lo, hi


def test_rotation_z_to_is_a_rotation_taking_z_to_the_direction(rng):
    for d in [*rng.normal(size=(20, 3)), np.array([0, 0, -2.0]), np.array([1e-3, 0, 0])]:
        R = rotation_z_to(d)
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
        np.testing.assert_allclose(R[:, 2], d / np.linalg.norm(d), atol=1e-12)


def test_clearance_and_sphere_collides_match_exact_box_distances(rng):
    boxes, lo, hi = random_boxes(rng)
    world = CollisionWorld(boxes)
    pts = rng.uniform(-5, 6, (300, 3))
    r = 0.25
    exact = box_sdf(pts, lo, hi)
    nearest_exact = exact.min(axis=1) - r
    got = np.array([world.clearance(p, r) for p in pts])
    free = nearest_exact > 1e-6
    np.testing.assert_allclose(
        got[free], nearest_exact[free], atol=1e-6, err_msg="clearance differs from exact distance"
    )
    # In contact: fcl's signed distance is minus the penetration depth (EPA, approximate).
    assert np.all(got[nearest_exact < -1e-3] < 0)
    np.testing.assert_allclose(got[~free], nearest_exact[~free], atol=2e-3)
    collides = np.array([world.sphere_collides(p, r) for p in pts])
    decisive = np.abs(nearest_exact) > 1e-6
    np.testing.assert_array_equal(collides[decisive], nearest_exact[decisive] < 0)
    # The reported nearest obstacle is the one of smallest exact distance.
    for p, row in zip(pts[free][:50], exact[free][:50], strict=True):
        if np.sort(row)[1] - row.min() > 1e-6:
            assert world.nearest(p, r)[1] == boxes[int(np.argmin(row))].name


def test_swept_collides_matches_dense_sampling_of_the_segment(rng):
    boxes, lo, hi = random_boxes(rng)
    world = CollisionWorld(boxes)
    r = 0.2
    s = np.linspace(0.0, 1.0, 4001)
    checked = 0
    for _ in range(200):
        p0 = rng.uniform(-5, 6, 3)
        p1 = p0 + rng.normal(size=3) * rng.uniform(0.05, 3.0)
        path = p0 + s[:, None] * (p1 - p0)
        gap = box_sdf(path, lo, hi).min() - r
        # Sampled minimum is off by at most half a sample spacing (distance is 1-Lipschitz).
        tol = 0.5 * np.linalg.norm(p1 - p0) / (len(s) - 1) + 1e-9
        if abs(gap) <= tol:
            continue
        checked += 1
        assert world.swept_collides(p0, p1, r) == (gap < 0), (p0, p1, gap)
        # with the start's clearance known, the same answer (short steps skip the capsule query)
        c0 = world.clearance(p0, r)
        assert world.swept_collides(p0, p1, r, clearance0=c0) == (gap < 0), (p0, p1, gap)
        short = p0 + 0.01 * (p1 - p0) / np.linalg.norm(p1 - p0)
        hit = box_sdf(p0 + s[:, None] * (short - p0), lo, hi).min() - r < 0
        if abs(box_sdf(p0 + s[:, None] * (short - p0), lo, hi).min() - r) > 1e-6:
            assert world.swept_collides(p0, short, r, clearance0=c0) == hit
    assert checked > 150
    with pytest.raises(GeometryError, match="clearance0"):
        world.swept_collides(p0, p1, r, clearance0="far")


def test_swept_capsule_catches_a_thin_wall_between_free_samples():
    world = CollisionWorld([Box("wall", (0.0, -5, -5), (0.05, 5, 5))])
    p0, p1 = np.array([-0.5, 0, 0]), np.array([0.6, 0, 0])
    assert not world.sphere_collides(p0, 0.2) and not world.sphere_collides(p1, 0.2)
    assert world.swept_collides(p0, p1, 0.2)
    assert world.contact_obstacles(p0, p1, 0.2) == ("wall",)
    # A degenerate segment is the sphere itself.
    assert world.swept_collides(p0, p0, 0.2) == world.sphere_collides(p0, 0.2)
    assert world.swept_collides([-0.1, 0, 0], [-0.1, 0, 0], 0.2)


def test_first_contact_index_matches_exact_geometry():
    boxes = [Box("near", (2.0, -1, -1), (3.0, 1, 1)), Box("far", (6.0, -1, -1), (7.0, 1, 1))]
    world = CollisionWorld(boxes)
    t = np.linspace(0, 1, 101)
    path = np.column_stack([10 * t, 0.3 * np.ones_like(t), np.zeros_like(t)])
    r = 0.25
    i = world.first_contact(path, r)
    # Exact: the first sample whose arrival segment comes within r of a box (x >= 2 - r).
    exact = int(np.argmax(path[:, 0] >= 2.0 - r))
    assert i == exact
    assert world.contact_obstacles(path[i - 1], path[i], r) == ("near",)
    assert world.first_contact(path[:exact], r) is None
    assert world.first_contact(np.array([[2.5, 0, 0], [9, 9, 9]]), r) == 0
    clear = world.clearances(path[:5], r)
    np.testing.assert_allclose(clear, 2.0 - path[:5, 0] - r, atol=1e-6)


def test_touching_reports_every_obstacle_hit():
    boxes = [Box("a", (1, -1, -1), (2, 1, 1)), Box("b", (4, -1, -1), (5, 1, 1))]
    world = CollisionWorld(boxes)
    assert world.contact_obstacles([0, 0, 0], [6, 0, 0], 0.1) == ("a", "b")
    assert world.contact_obstacles([0, 3, 0], [6, 3, 0], 0.1) == ()


def test_mesh_obstacles_convex_solid_and_nonconvex_surface():
    cube = trimesh.creation.box(extents=(2, 2, 2))
    torus = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)
    world = CollisionWorld(
        meshes=[
            MeshObstacle("cube", cube.vertices + [5, 0, 0], cube.faces),
            MeshObstacle("torus", torus.vertices + [0, 5, 0], torus.faces),
        ]
    )
    pts = np.array([[2.5, 0, 0], [3.7, 0.5, 0.2], [5.0, 0.0, 0.0], [5.5, 0.5, 0.5]])
    exact = box_sdf(pts, np.array([[4.0, -1, -1]]), np.array([[6.0, 1, 1]]))[:, 0] - 0.3
    got = np.array([world.clearance(p, 0.3) for p in pts])
    np.testing.assert_allclose(got[:2], exact[:2], atol=1e-6, err_msg="convex mesh distance")
    # Convex meshes are solid: a body wholly inside collides and has negative clearance.
    assert world.sphere_collides(pts[2], 0.3) and got[2] < 0 and got[3] < 0
    # The torus hole is free; a body crossing its tube is caught by the swept capsule.
    assert not world.sphere_collides([0, 5, 0], 0.3)
    assert world.contact_obstacles([1, 5, 2], [1, 5, -2], 0.05) == ("torus",)
    assert world.nearest([0, 5, 0], 0.3) == pytest.approx((1.0 - 0.3 - 0.3, "torus"), abs=2e-2)


def test_voxel_boxes_collide_as_solid_boxes(rng):
    centres = rng.uniform(-2, 2, (40, 3)).round(1)
    vb = voxel_boxes_from_centres(centres, 0.1)
    world = CollisionWorld(voxel_boxes=vb)
    pts = rng.uniform(-3, 3, (100, 3))
    exact = box_sdf(pts, vb[:, 0], vb[:, 1]).min(axis=1) - 0.05
    got = np.array([world.clearance(p, 0.05) for p in pts])
    free = exact > 1e-6
    np.testing.assert_allclose(got[free], exact[free], atol=1e-6)
    assert world.nearest(centres[0], 0.05)[1] == VOXEL_NAME


def test_voxel_leaves_merge_into_fewer_boxes_with_the_same_union(rng):
    """An OctoMap's leaves (voxels, and pruned leaves 2 or 4 voxels wide) become fewer boxes for
    fcl: every point is as far from their union as from the leaves', inside or out."""
    res = 0.08
    wall = np.stack(np.meshgrid(np.arange(12), np.arange(12), [0, 1], indexing="ij"), -1)
    clutter = rng.integers(0, 12, (300, 3))
    keys = np.unique(np.concatenate([wall.reshape(-1, 3), clutter]), axis=0)  # unit leaves
    pruned = np.array([[20, 0, 0], [20, 2, 0], [24, 4, 4]])  # 2-wide, 2-wide and 4-wide leaves
    sizes = np.array([2, 2, 4])
    lo = (np.concatenate([keys, pruned]) - 7) * res  # corners (key - 32768) * res, as OctoMap's
    hi = lo + np.concatenate([np.ones(len(keys)), sizes])[:, None] * res
    leaves = np.stack([lo, hi], axis=1)
    merged = merged_voxel_boxes(leaves)
    assert len(merged) < len(leaves) / 3
    pts = np.concatenate(
        [
            rng.uniform(lo.min(0) - 0.2, hi.max(0) + 0.2, (3000, 3)),
            lo[rng.integers(0, len(lo), 2000)] + rng.uniform(-0.01, 0.01, (2000, 3)),  # at corners
        ]
    )
    want = box_sdf(pts, leaves[:, 0], leaves[:, 1]).min(axis=1)
    got = box_sdf(pts, merged[:, 0], merged[:, 1]).min(axis=1)
    outside = want > 0
    np.testing.assert_allclose(got[outside], want[outside], atol=1e-9)
    np.testing.assert_array_equal(got <= 1e-12, want <= 1e-12)  # the same points inside
    world = CollisionWorld(voxel_boxes=leaves)
    some = np.flatnonzero(want > 0.05)[:20]
    np.testing.assert_allclose(
        [world.clearance(p, 0.05) for p in pts[some]], want[some] - 0.05, atol=1e-6
    )
    # boxes off any common grid are left as they are
    odd = leaves.copy()
    odd[0] += 0.013
    assert merged_voxel_boxes(odd) is not None and len(merged_voxel_boxes(odd)) == len(odd)


def test_empty_world_and_bad_input():
    world = CollisionWorld()
    assert world.empty and not world.sphere_collides([0, 0, 0], 1.0)
    assert world.clearance([0, 0, 0], 1.0) == np.inf
    assert world.first_contact(np.zeros((3, 3)), 0.1) is None
    with pytest.raises(GeometryError, match="radius"):
        world.sphere_collides([0, 0, 0], -1.0)
    with pytest.raises(GeometryError, match="p0"):
        world.swept_collides([0, 0], [0, 0, 0], 0.1)
    with pytest.raises(GeometryError, match="path"):
        world.first_contact(np.zeros((3, 2)), 0.1)


def test_worlds_of_one_voxel_set_share_shapes_and_outlive_each_other(rng):
    """Two collision worlds of the same voxels share their fcl shapes (built once) and answer
    alike; the second still answers after the first is gone and the cache has moved on."""
    import gc

    from secure3d.simulation import scene

    centres = (np.unique(rng.integers(0, 20, size=(400, 3)), axis=0) + 0.5) * 0.1
    vb = voxel_boxes_from_centres(centres, 0.1)
    first, second = CollisionWorld(voxel_boxes=vb), CollisionWorld(voxel_boxes=vb)
    assert first._geoms[0] is second._geoms[0]
    probes = rng.uniform(-0.2, 2.2, size=(60, 3))
    answers = [first.nearest(p, 0.05) for p in probes]
    del first
    for k in range(scene.CONTENT_CACHE_SIZE + 1):  # push the shapes out of the cache
        CollisionWorld(voxel_boxes=vb + 10.0 * (k + 1))
    gc.collect()
    assert [second.nearest(p, 0.05) for p in probes] == answers
    inside = centres[0]
    assert second.sphere_collides(inside, 0.01) and VOXEL_NAME in second.names
