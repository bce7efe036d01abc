"""Sticky hits and the observed range, with the real ray-cast camera (issue 16, items 1 and 2)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from secure3d.errors import ConfigError
from secure3d.mapping import OccupancyMap, Trust
from secure3d.mapping.keys import coords_to_codes
from secure3d.mapping.observability import observed_range, observed_sides, rays_needed
from secure3d.simulation.camera import DepthCamera
from secure3d.world.spec import CameraSpec

# optical frame (z forward, x right, y down) looking along world +x
LOOK_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def test_a_hit_voxel_stays_a_known_obstacle_when_later_rays_carve_its_log_odds():
    m = OccupancyMap(0.1)
    voxel = np.array([[5.05, 0.05, 1.05]])
    origin = np.array([0.0, 0.05, 1.05])
    grazing = np.array([[10.0, 0.05 + d, 1.05] for d in (-0.03, 0.0, 0.03)])
    for _ in range(10):  # rays through the voxel to the ground behind: carved to the clamp
        m.insert_point_cloud(grazing, origin)
    assert m.trust(voxel)[0] == Trust.SENSED_FREE
    m.insert_point_cloud([[5.07, 0.05, 1.05]], origin)  # the first hit
    # OctoMap's log-odds say free (-2.0 + 0.85); the safety layer says obstacle
    assert m.classify(voxel)[0] == 0
    assert m.trust(voxel)[0] == Trust.SENSED_OCCUPIED and m.is_known_obstacle(voxel)[0]
    for _ in range(10):
        m.insert_point_cloud(grazing, origin)
    code, _ = coords_to_codes(voxel, 0.1)
    assert m.is_known_obstacle_sensed(code)[0] and m.is_known_obstacle(voxel)[0]
    assert any(np.allclose(c, voxel[0]) for c in m.known_obstacle_voxels())
    lo, hi = m.known_obstacle_boxes(close_gaps=0)
    assert np.any(np.all((lo <= voxel) & (voxel <= hi), axis=1))
    # the server's claim never clears a sensed hit, and copies keep it
    m.set_claim_voxels(voxel, occupied=False)
    assert m.is_known_obstacle(voxel)[0] and m.copy().is_known_obstacle(voxel)[0]
    # the OctoMap layer and its files are OctoMap's: the voxel is free there
    assert OccupancyMap.from_bytes(m.to_bytes("ot")).classify(voxel)[0] == 0
    assert not OccupancyMap.from_bytes(m.to_bytes("bt")).is_known_obstacle(voxel)[0]


def _thin(kind: str, size: float, x: float) -> trimesh.Trimesh:
    """A pole (vertical), plank (horizontal board across the route, ``size`` thick) or wire
    (horizontal bar across the route, ``size`` square) in front of a camera on the x axis."""
    if kind == "pole":
        extents, centre = (size, size, 2.5), (x, 0.013, 1.25)
    elif kind == "plank":
        extents, centre = (0.3, 1.5, size), (x, 0.0, 1.03)
    else:
        extents, centre = (size, 3.0, size), (x, 0.0, 1.013)
    return trimesh.creation.box(
        extents=extents, transform=trimesh.transformations.translation_matrix(centre)
    )


def _approach(kind: str, size: float, speed: float, discretize: bool = True):
    """Fly a 64 x 48 camera at ``speed`` (15 Hz) from 7 m to 0.6 m in front of the obstacle, over
    a floor; yield the map after each frame and whether that frame hit the obstacle."""
    spec = CameraSpec(width=64, height=48, hfov_deg=90, max_range=8.0, discretize=discretize)
    floor = trimesh.creation.box(
        extents=(20, 6, 0.2), transform=trimesh.transformations.translation_matrix((5, 0, -0.1))
    )
    cam = DepthCamera(spec, [("floor", floor), ("thin", _thin(kind, size, 7.0))])
    m = OccupancyMap(0.1)
    x = 0.0
    while x < 6.4:
        o = np.array([x, 0.0, 1.0])
        f = cam.render(LOOK_X, o)
        m.insert_depth_image(
            f.depth, (f.fx, f.fy, f.cx, f.cy), LOOK_X, o, 8.0, discretize=discretize
        )
        yield m, "thin" in f.hit_names(), x
        x += speed / spec.rate_hz


@pytest.mark.parametrize("speed", [2.0, 5.0])
@pytest.mark.parametrize(
    ("kind", "size"),
    [
        ("pole", 0.04),
        ("pole", 0.15),
        ("plank", 0.03),
        ("plank", 0.2),
        ("wire", 0.02),
        ("wire", 0.15),
    ],
)
def test_a_thin_obstacle_once_hit_stays_a_known_obstacle_all_the_way_in(kind, size, speed):
    """Poles, planks and wires below and above the default min_obstacle_size (0.15 m), approached at
    2 and 5 m/s: from the first frame that hits the obstacle on, the map holds a known obstacle
    voxel overlapping it in every later frame (OctoMap's log-odds alone lose the pole's voxel to
    grazing rays between hits)."""
    thin = _thin(kind, size, 7.0)
    lo, hi = thin.bounds
    seen_at = None
    for m, hit, x in _approach(kind, size, speed):
        seen_at = x if hit and seen_at is None else seen_at
        if seen_at is None:
            continue
        occ = m.known_obstacle_voxels()
        touching = np.all((occ + 0.05 > lo) & (occ - 0.05 < hi), axis=1)
        assert touching.any(), f"{kind} {size} m: no known obstacle voxel on it at x = {x:.2f} m"
    assert seen_at is not None, f"{kind} {size} m never seen"


@pytest.mark.parametrize("size", [0.04, 0.1])
def test_every_frame_hits_an_obstacle_of_min_size_within_the_observed_range(size):
    """A ball of diameter w (the class the guarantee covers) anywhere in the image at depth up to
    the observed range is hit by every frame; at twice that depth some placements are missed (the
    pixel grid really is the limit)."""
    spec = CameraSpec(width=64, height=48, hfov_deg=90, max_range=8.0)
    z_obs = observed_range(spec.fx, spec.fy, 8.0, "depth", 0.1, min_obstacle_size=size)
    rng = np.random.default_rng(0)
    misses = {}
    for scale in (1.0, 2.0):
        missed = 0
        for _ in range(60):
            z = scale * rng.uniform(0.5, 1.0) * z_obs
            # inside the image by the ball's radius
            u = rng.uniform(-1, 1) * (z * spec.width / (2 * spec.fx) - size)
            v = rng.uniform(-1, 1) * (z * spec.height / (2 * spec.fy) - size)
            ball = trimesh.creation.icosphere(subdivisions=3, radius=size / 2)
            ball.apply_translation((z, -u, -v))
            cam = DepthCamera(spec, [("ball", ball)])
            missed += "ball" not in cam.render(LOOK_X, np.zeros(3)).hit_names()
        misses[scale] = missed
    assert misses[1.0] == 0, misses
    assert misses[2.0] > 0, misses


def _border_ball_centre(rng, spec, frustum, size, z, corner):
    """A point q on the boundary of ``frustum``'s side faces at depth z (on two faces at a corner),
    and the centre of a ball of diameter ``size`` through q pushed out of the image as far as it
    goes (along the image planes' outward normals): the worst placement the faces allow."""
    tans = (spec.width / (2 * spec.fx), spec.height / (2 * spec.fy))
    s, off, e = frustum.side_shrink, frustum.side_offset, frustum.side_margin
    q, out = np.zeros(3), np.zeros(3)
    q[2] = z
    axes = (0, 1) if corner else (int(rng.integers(2)),)
    for axis in (0, 1):
        t = tans[axis] - s
        edge = (t * z + off) - e * np.hypot(1.0, t)  # |x| on the face at depth z
        sign = rng.choice([-1.0, 1.0])
        if axis in axes:
            q[axis] = sign * edge
            n = np.zeros(3)
            n[axis], n[2] = sign, -tans[axis]  # the image plane's outward normal
            out += n / np.linalg.norm(n)
        else:
            q[axis] = rng.uniform(-1, 1) * edge
    return q + 0.5 * size * out / np.linalg.norm(out)


@pytest.mark.parametrize("size", [0.04, 0.15])
def test_a_ball_touching_the_observed_field_of_view_at_its_side_is_hit(size):
    """The side faces of the observed field of view (observed_sides): a ball of diameter w through
    any point of them, pushed out of the image as far as it goes, is hit by the frame, along every
    border and at the corners, from the near face out to the observed range. On the image's own
    border (no allowance) some such balls are missed."""
    from secure3d.geometry.frustum import PinholeFrustum

    spec = CameraSpec(width=64, height=48, hfov_deg=90, max_range=8.0)
    z_obs = observed_range(spec.fx, spec.fy, 8.0, "depth", 0.1, min_obstacle_size=size)
    margin, offset, shrink, near = observed_sides(spec.fx, spec.fy, size)
    assert margin == pytest.approx(size / 2) and near == pytest.approx(size / 2)
    observed = PinholeFrustum(
        spec.hfov,
        spec.vfov,
        z_obs,
        side_margin=margin,
        side_offset=offset,
        side_shrink=shrink,
        near=near,
    )
    border = PinholeFrustum(spec.hfov, spec.vfov, z_obs)
    ball = trimesh.creation.icosphere(subdivisions=3, radius=size / 2)
    rng = np.random.default_rng(1)
    misses = {}
    for name, frustum in (("observed", observed), ("border", border)):
        missed = 0
        for k in range(80):
            lowest = max(near, 0.6 * size) if name == "observed" else 0.6 * size
            z = rng.uniform(lowest, z_obs) if k % 3 else z_obs
            c = _border_ball_centre(rng, spec, frustum, size, z, corner=k % 4 == 0)
            placed = ball.copy()
            placed.apply_translation((c[2], -c[0], -c[1]))  # optical (x, y, z) -> world
            cam = DepthCamera(spec, [("ball", placed)])
            missed += "ball" not in cam.render(LOOK_X, np.zeros(3)).hit_names()
        misses[name] = missed
    assert misses["observed"] == 0, misses
    assert misses["border"] > 0, misses


def test_the_observed_sides_follow_the_size_the_pixels_and_dropout():
    margin, offset, shrink, near = observed_sides(80, 80, 0.1)
    z_res = 0.1 * 80 / math.sqrt(2)
    assert (margin, near) == (pytest.approx(0.05), pytest.approx(0.05))
    assert offset == pytest.approx(0.05 / math.sqrt(2))
    assert shrink == pytest.approx(offset / z_res)
    # with dropout: the square of m x m rays round the centre inside the image's own planes
    assert observed_sides(80, 80, 0.1, dropout=0.05) == pytest.approx(
        (0.05 * (1 + 1 / math.sqrt(2)), 0.0, 0.0, 0.05)
    )
    with pytest.raises(ConfigError, match="min_obstacle_size"):
        observed_sides(80, 80, -1.0)


def test_discretized_frames_mark_the_same_hit_voxels_as_every_pixel():
    """OctoMap's discretize casts one ray per end voxel but marks every end voxel occupied, so a
    thin obstacle the full pixel grid hits is never skipped."""
    full = list(_approach("wire", 0.02, 5.0, discretize=False))
    disc = list(_approach("wire", 0.02, 5.0, discretize=True))
    for (mf, _, _), (md, _, _) in zip(full, disc, strict=True):
        a = {tuple(c) for c in np.round(mf.known_obstacle_voxels(), 3)}
        b = {tuple(c) for c in np.round(md.known_obstacle_voxels(), 3)}
        assert a == b


def test_the_observed_range_follows_resolution_dropout_and_range_limits():
    base = observed_range(80, 80, 20.0, "depth", 0.1, min_obstacle_size=0.1)
    assert base == pytest.approx(0.1 * 80 / math.sqrt(2) - 0.05)
    assert observed_range(80, 80, 3.0, "depth", 0.1) == 3.0
    # a range-limited discretised frame loses hits whose voxel centre lies beyond the range
    assert observed_range(80, 80, 3.0, "range", 0.1, discretize=True) == pytest.approx(
        3.0 - 0.05 * math.sqrt(3)
    )
    assert observed_range(80, 80, 3.0, "range", 0.1, discretize=False) == 3.0
    # with the edge allowance a sensor limit counts w / 2 short (a ray reaches the ball through a
    # seen point at most w / 2 deeper), w short for a Euclidean range
    edge = {"edge_allowance": True}
    assert observed_range(80, 80, 3.0, "depth", 0.1, **edge) == pytest.approx(3.0 - 0.075)
    assert observed_range(80, 80, 3.0, "range", 0.1, discretize=True, **edge) == pytest.approx(
        3.0 - 0.05 * math.sqrt(3) - 0.15
    )
    assert observed_range(80, 80, 20.0, "depth", 0.1, min_obstacle_size=0.1, **edge) == base
    with pytest.raises(ConfigError, match="max_range 0.1 m leaves no surely observed depth"):
        observed_range(80, 80, 0.1, "range", 0.1, **edge)
    # dropout: enough rays that losing all of them has probability <= 1e-6 per frame
    assert rays_needed(0.0) == 1 and rays_needed(0.05) == 5 and 0.05**5 <= 1e-6
    assert observed_range(80, 80, 20.0, "depth", 0.1, dropout=0.05) < base / 2
    for bad in (
        {"min_obstacle_size": 0.0},
        {"min_obstacle_size": float("nan")},
        {"dropout": 1.0},
    ):
        with pytest.raises(ConfigError, match="observed_range"):
            observed_range(80, 80, 3.0, "depth", 0.1, **bad)


def test_known_obstacle_runs_equal_the_filter_over_every_sensed_voxel():
    """The sensed-occupied run (voxels at or above the threshold, and hit ones) equals the
    definition over all sensed voxels, on a map with coarse leaves, carving and sticky hits."""
    from secure3d.mapping.keys import unique_sorted

    rng = np.random.default_rng(5)
    m = OccupancyMap(0.1)
    origin = np.array([0.05, 0.05, 1.05])
    for _ in range(6):
        m.insert_point_cloud(rng.uniform([1, -2, 0], [4, 2, 2], (300, 3)), origin)
    m.insert_point_cloud(rng.uniform([1, -2, 0], [6, 2, 2], (200, 3)), origin)  # carves some hits
    codes, vals = m._sensor_voxels()
    occ = (vals >= m._params.threshold_log) | m._hits.contains(codes)
    _, sensed = m._known_obstacle_runs()
    np.testing.assert_array_equal(sensed, unique_sorted(codes[occ]))
    assert sensed.dtype == np.int64 and 0 < len(sensed) < len(codes)
    assert np.any(m._hits.contains(codes) & (vals < m._params.threshold_log))  # carved, kept
    # coarse leaves: the layer's filtered codes equal the filter over its expanded voxels
    from secure3d.mapping.store import LeafLayer

    layer = LeafLayer()
    starts = np.array([0, 8, 16, 64 + 512, 5000], dtype=np.int64)
    depths = np.array([15, 15, 16, 14, 16], dtype=np.int8)
    values = np.array([0.5, -1.0, 0.2, 0.9, -0.1], dtype=np.float32)
    layer.set_leaves(starts, depths, values)
    codes, vals = layer.voxels()
    for threshold in (0.0, 0.3, -2.0):
        np.testing.assert_array_equal(layer.voxels_at_least(threshold), codes[vals >= threshold])
