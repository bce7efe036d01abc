"""Depth camera: Open3D ray casting cross-checked against analytic ray/box intersection."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from secure3d._deps import open3d
from secure3d.errors import ConfigError, GeometryError
from secure3d.simulation.camera import NO_HIT, DepthCamera, pixel_rays
from secure3d.simulation.scene import world_trimesh
from secure3d.world.spec import Box, CameraSpec

# Optical z -> world +x, optical x (right) -> world -y, optical y (down) -> world -z.
R_LOOK_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def slab_depth(origin, dirs, lo, hi):
    """First hit ``t`` of rays ``origin + t * dirs`` (n, 3) with boxes (m, 3): (n,), inf if none.

    The classic slab method; with unit-z optical rays ``t`` is the z-depth.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs[:, None, :]
        t1 = (lo[None] - origin) * inv
        t2 = (hi[None] - origin) * inv
    tnear = np.nanmax(np.minimum(t1, t2), axis=-1)
    tfar = np.nanmin(np.maximum(t1, t2), axis=-1)
    hit = (tnear <= tfar) & (tfar > 0)
    t = np.where(hit, np.maximum(tnear, 0.0), np.inf)
    return t.min(axis=1), np.where(np.isfinite(t.min(axis=1)), t.argmin(axis=1), -1)


def test_pixel_rays_are_open3d_create_rays_pinhole():
    o3d = open3d()
    K = np.array([[100.0, 0, 80], [0, 90, 60], [0, 0, 1]])
    rays = o3d.t.geometry.RaycastingScene.create_rays_pinhole(
        o3d.core.Tensor(K), o3d.core.Tensor(np.eye(4)), 160, 120
    ).numpy()
    np.testing.assert_allclose(rays[..., 3:], pixel_rays(160, 120, 100, 90, 80, 60), atol=1e-6)


def test_depth_is_z_depth_and_matches_analytic_ray_box_intersection(rng):
    lo = rng.uniform(-6, 6, (25, 3))
    hi = lo + rng.uniform(0.3, 2.0, (25, 3))
    boxes = [Box(f"b{i}", tuple(lo[i]), tuple(hi[i])) for i in range(25)]
    spec = CameraSpec(width=64, height=48, hfov_deg=80, max_range=50.0)
    cam = DepthCamera(spec, world_trimesh(boxes))
    origin = np.array([0.0, 0.0, 8.0])  # above every box: the camera is outside them all
    checked = 0
    for _ in range(6):
        R = random_rotation(rng)
        frame = cam.render(R, origin)
        dirs = frame.rays_optical().reshape(-1, 3) @ R.T
        t, which = slab_depth(origin, dirs, lo, hi)
        got = frame.depth.reshape(-1).astype(float)
        np.testing.assert_array_equal(np.isfinite(got), np.isfinite(t), err_msg="hit pattern")
        np.testing.assert_allclose(got[np.isfinite(t)], t[np.isfinite(t)], rtol=1e-5, atol=1e-4)
        hit_name = np.array([b.name for b in boxes] + ["-"])[which]
        ids = frame.hit_ids.reshape(-1)
        got_name = np.array([*frame.names, "-"])[np.where(ids == NO_HIT, -1, ids)]
        # Pixels grazing an edge shared by two boxes may legitimately name either.
        agree = np.mean(hit_name[np.isfinite(t)] == got_name[np.isfinite(t)])
        assert agree > 0.99
        pts = frame.points_world()
        np.testing.assert_allclose(
            pts, origin + t[np.isfinite(t), None] * dirs[np.isfinite(t)], atol=1e-3
        )
        checked += int(np.isfinite(t).sum())
    assert checked > 1000


def test_far_limit_depth_versus_range():
    wall = [Box("wall", (5.0, -50, -50), (6.0, 50, 50))]
    mesh = world_trimesh(wall)
    base = CameraSpec(width=40, height=30, hfov_deg=90, max_range=5.01, far_kind="depth")
    depth = DepthCamera(base, mesh).render(R_LOOK_X, np.zeros(3)).depth
    np.testing.assert_allclose(depth, 5.0, atol=1e-4, err_msg="z-depth of a fronto-parallel wall")
    short = dataclasses.replace(base, max_range=4.99)
    assert np.all(np.isinf(DepthCamera(short, mesh).render(R_LOOK_X, np.zeros(3)).depth))
    ranged = dataclasses.replace(base, max_range=6.0, far_kind="range")
    frame = DepthCamera(ranged, mesh).render(R_LOOK_X, np.zeros(3))
    euclid = 5.0 * np.linalg.norm(frame.rays_optical(), axis=-1)
    np.testing.assert_array_equal(np.isfinite(frame.depth), euclid <= 6.0)
    assert 0 < np.isfinite(frame.depth).mean() < 1


def test_occlusion_hides_what_is_behind():
    boxes = [Box("front", (3, -10, -10), (3.5, 10, 10)), Box("back", (6, -1, -1), (7, 1, 1))]
    spec = CameraSpec(width=32, height=24, max_range=20.0)
    cam = DepthCamera(spec, world_trimesh(boxes))
    frame = cam.render(R_LOOK_X, np.zeros(3))
    assert frame.hit_names() == {"front"}
    assert frame.hit_counts() == {"front": 32 * 24}
    seen_from_behind = cam.render(R_LOOK_X, np.array([4.0, 0, 0]))
    assert seen_from_behind.hit_names() == {"back"}


def test_noise_and_dropout_statistics_and_reproducibility():
    mesh = world_trimesh([Box("wall", (5.0, -50, -50), (6.0, 50, 50))])
    spec = CameraSpec(width=160, height=120, max_range=20.0, noise_std=0.05, dropout=0.2)
    a = DepthCamera(spec, mesh, rng=np.random.default_rng(7)).render(R_LOOK_X, np.zeros(3))
    b = DepthCamera(spec, mesh, rng=np.random.default_rng(7)).render(R_LOOK_X, np.zeros(3))
    np.testing.assert_array_equal(a.depth, b.depth)
    dropped = np.isnan(a.depth)
    n = dropped.size
    # Binomial(n, 0.2): five standard deviations.
    assert abs(dropped.mean() - 0.2) < 5 * np.sqrt(0.2 * 0.8 / n)
    assert np.all(a.hit_ids[dropped] == NO_HIT)
    err = a.depth[~dropped] - 5.0
    assert abs(err.mean()) < 5 * 0.05 / np.sqrt(err.size)
    np.testing.assert_allclose(err.std(), 0.05, rtol=0.05)
    assert len(a.points_world()) == int((~dropped).sum())


def test_unlabelled_mesh_empty_world_and_bad_input():
    cube = trimesh.creation.box(extents=(1, 1, 1))
    cube.apply_translation([3, 0, 0])
    spec = CameraSpec(width=16, height=12)
    assert DepthCamera(spec, cube).render(R_LOOK_X, np.zeros(3)).hit_names() == {"world"}
    named = DepthCamera(spec, [("cube", cube)]).render(R_LOOK_X, np.zeros(3))
    assert named.hit_names() == {"cube"}
    empty = DepthCamera(spec, world_trimesh()).render(R_LOOK_X, np.zeros(3))
    assert np.all(np.isinf(empty.depth)) and empty.points_world().shape == (0, 3)
    cam = DepthCamera(spec, cube)
    with pytest.raises(GeometryError, match="rotation"):
        cam.render(2 * np.eye(3), np.zeros(3))
    with pytest.raises(GeometryError, match="origin"):
        cam.render(np.eye(3), np.zeros(2))
    with pytest.raises(ConfigError, match="CameraSpec"):
        DepthCamera({"width": 16}, cube)


def test_blind_corner_hides_the_crate_until_the_robot_turns(maps_dir):
    from secure3d.dynamics import model_from_spec
    from secure3d.world.attacks import true_obstacles
    from secure3d.world.scenario import load_scenario

    scenario = load_scenario(maps_dir / "blind_corner.yaml")
    truth = true_obstacles(scenario)
    model = model_from_spec(scenario.vehicle, scenario.camera)
    cam = DepthCamera(scenario.camera, world_trimesh(truth.boxes, truth.meshes, truth.voxel_boxes))
    start = model.initial_state(scenario.start.position, yaw=scenario.start.yaw)
    seen_at_start = cam.render(*model.camera_pose(start)).hit_names()
    assert "crate" in scenario.hidden_obstacles and "crate" not in seen_at_start
    assert {"inner_block", "floor"} <= seen_at_start
    assert "wall_east" not in seen_at_start, "7 m away: beyond the 6 m depth limit"
    turned = model.initial_state([6.75, 1.25, 1.25], yaw=np.pi / 2)
    assert "crate" in cam.render(*model.camera_pose(turned)).hit_names()


def _voxel_world(rng, pitch=0.08, n=600):
    """Grid-aligned cubes of one, two and four cells (an OctoMap's leaves), many touching."""
    cells = rng.integers(0, 12, size=(n, 3))
    size = rng.choice([1, 1, 1, 2, 4], size=n)
    lo = (cells - cells % size[:, None]) * pitch  # a coarse leaf starts at a multiple of its size
    lo, idx = np.unique(np.round(lo, 9), axis=0, return_index=True)
    hi = lo + size[idx, None] * pitch
    return np.stack([lo, hi], axis=1)


def test_exposed_voxel_faces_give_the_same_depth_images_as_every_face():
    import trimesh as tm

    from secure3d.simulation.scene import VOXEL_NAME, box_arrays, exposed_sides, labelled_union

    rng = np.random.default_rng(11)
    vb = _voxel_world(rng)
    sides = exposed_sides(vb[:, 0], vb[:, 1])
    assert sides is not None and 0 < sides.sum() < sides.size  # some faces are covered
    import secure3d.simulation.scene as scene_module

    dense_cells = scene_module._DENSE_CELLS
    try:  # the sorted-key form for grids too large for a dense array: the same sides
        scene_module._DENSE_CELLS = 0
        np.testing.assert_array_equal(exposed_sides(vb[:, 0], vb[:, 1]), sides)
    finally:
        scene_module._DENSE_CELLS = dense_cells
    v, f = box_arrays(vb[:, 0], vb[:, 1])
    full = labelled_union([(VOXEL_NAME, tm.Trimesh(v, f, process=False))])
    reduced = world_trimesh(voxel_boxes=vb)
    assert len(reduced.faces) == 2 * sides.sum() < len(full.faces)
    spec = CameraSpec(width=48, height=36, hfov_deg=90, max_range=3.0)
    cam_full, cam_reduced = DepthCamera(spec, full), DepthCamera(spec, reduced)
    poses = 0
    while poses < 40:
        o = rng.uniform(-0.3, 1.3, 3)
        if np.any(np.all((vb[:, 0] <= o) & (o <= vb[:, 1]), axis=1)):
            continue  # a camera inside a voxel sees its inner faces
        R = random_rotation(rng)
        a, b = cam_full.render(R, o), cam_reduced.render(R, o)
        np.testing.assert_array_equal(a.depth, b.depth)
        np.testing.assert_array_equal(a.hit_ids, b.hit_ids)
        poses += 1


def test_boxes_off_a_common_grid_keep_every_face():
    from secure3d.simulation.scene import exposed_sides

    lo = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    assert exposed_sides(lo, lo + 0.08) is None
    assert len(world_trimesh(voxel_boxes=np.stack([lo, lo + 0.08], axis=1)).faces) == 24
    lo = np.array([[0.0, 0.0, 0.0], [0.08, 0.0, 0.0]])
    sides = exposed_sides(lo, lo + 0.08)
    assert sides.tolist() == [[True, False] + [True] * 4, [False, True] + [True] * 4]
