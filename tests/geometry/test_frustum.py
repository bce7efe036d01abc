"""Camera frustum: half-spaces checked against angles and pixel projection built independently."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from secure3d.errors import ConfigError, GeometryError
from secure3d.geometry.ellipsoid import ellipsoid_from_axes, halfspace_margins, surface_points
from secure3d.geometry.frustum import (
    PinholeFrustum,
    ellipsoid_in_frustum_margin,
    frustum_corners,
    frustum_halfspaces,
    points_in_frustum,
)
from secure3d.geometry.transforms import camera_rotation, yaw_matrix


def random_pose(rng):
    R = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
    return R, rng.uniform(-5, 5, 3)


def points_around_camera(rng, n, far):
    """Optical-frame points spread over and beyond the field of view (some behind the camera)."""
    return rng.uniform([-far, -far, -0.2 * far], [far, far, 1.3 * far], (n, 3))


def test_config_validation():
    with pytest.raises(ConfigError, match="hfov"):
        PinholeFrustum(hfov=0.0, vfov=1.0, far=5.0)
    with pytest.raises(ConfigError, match="vfov"):
        PinholeFrustum(hfov=1.0, vfov=math.pi, far=5.0)
    with pytest.raises(ConfigError, match="far"):
        PinholeFrustum(hfov=1.0, vfov=1.0, far=-1.0)
    with pytest.raises(ConfigError, match="far_kind"):
        PinholeFrustum(hfov=1.0, vfov=1.0, far=5.0, far_kind="sphere")
    with pytest.raises(ConfigError, match="hfov"):
        PinholeFrustum(hfov=float("nan"), vfov=1.0, far=5.0)
    with pytest.raises(ConfigError, match="principal_x"):
        PinholeFrustum(hfov=1.0, vfov=1.0, far=5.0, principal_x=1.5)
    with pytest.raises(ConfigError, match="fx"):
        PinholeFrustum.from_intrinsics(fx=0, fy=100, width=320, height=240, far=5)
    with pytest.raises(GeometryError, match="PinholeFrustum"):
        frustum_halfspaces(np.eye(3), np.zeros(3), "not a frustum")


def test_points_classified_like_the_view_angles(rng):
    fr = PinholeFrustum(hfov=np.radians(90), vfov=np.radians(60), far=6.0)
    p_opt = points_around_camera(rng, 20_000, fr.far)
    # Independent rule: horizontal and vertical angles to the optical axis, and the depth.
    h_angle = np.arctan2(p_opt[:, 0], p_opt[:, 2])
    v_angle = np.arctan2(p_opt[:, 1], p_opt[:, 2])
    inside = (np.abs(h_angle) <= fr.hfov / 2) & (np.abs(v_angle) <= fr.vfov / 2)
    inside &= (p_opt[:, 2] > 0) & (p_opt[:, 2] <= fr.far)
    assert 1000 < inside.sum() < 19_000
    R, o = random_pose(rng)
    p_world = o + p_opt @ R.T
    np.testing.assert_array_equal(points_in_frustum(R, o, fr, p_world), inside)
    A, b = frustum_halfspaces(R, o, fr)
    np.testing.assert_allclose(np.linalg.norm(A, axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(np.all(p_world @ A.T <= b, axis=1), inside)
    # margin: a point 0.1 m inside every face passes, the same point with margin 0.2 fails.
    centre = o + R @ [0, 0, 3.0]
    depth_to_side = 3.0 * np.sin(fr.vfov / 2)  # distance to the top/bottom plane at depth 3
    assert points_in_frustum(R, o, fr, centre[None], margin=depth_to_side - 0.05)[0]
    assert not points_in_frustum(R, o, fr, centre[None], margin=depth_to_side + 0.05)[0]


def test_observed_sides_move_the_side_planes_and_add_a_near_face(rng):
    """An observed field of view holds exactly the points ``side_margin`` inside the planes
    ``x = (t - side_shrink) z + side_offset`` of the image's edges, beyond the near face and inside
    the far face; the certificate's own camera margin (from the angles, not the half-spaces) is
    the same distance."""
    from secure3d.planning.certificate import _clear_views

    e, off, s, near = 0.12, 0.05, 0.03, 0.3
    fr = PinholeFrustum(
        np.radians(90),
        np.radians(60),
        6.0,
        side_margin=e,
        side_offset=off,
        side_shrink=s,
        near=near,
    )
    assert fr.n_faces == 6
    p_opt = points_around_camera(rng, 20_000, fr.far)
    th, tv = np.tan(fr.hfov / 2) - s, np.tan(fr.vfov / 2) - s
    h_gap = (th * p_opt[:, 2] + off - np.abs(p_opt[:, 0])) / np.hypot(1, th) - e
    v_gap = (tv * p_opt[:, 2] + off - np.abs(p_opt[:, 1])) / np.hypot(1, tv) - e
    gaps = np.stack([h_gap, v_gap, p_opt[:, 2] - near, fr.far - p_opt[:, 2]], axis=1)
    inside = gaps.min(axis=1) >= 0
    assert 500 < inside.sum() < 19_000
    R, o = random_pose(rng)
    p_world = o + p_opt @ R.T
    np.testing.assert_array_equal(points_in_frustum(R, o, fr, p_world), inside)
    # the certificate's view margin: the smallest gap minus the radius
    pts = p_world[inside][:200]
    args = (np.full(len(pts), 1), R[None], o[None])
    no_boxes = (np.zeros((0, 3)), np.zeros((0, 3)))
    _, _, raw, _ = _clear_views(pts, *args, fr, 0.05, *no_boxes, 1e-6)
    np.testing.assert_allclose(raw, gaps[inside][:200].min(axis=1) - 0.05, atol=1e-9)
    for field, bad in (("side_margin", -0.01), ("side_offset", float("nan")), ("near", -1.0)):
        with pytest.raises(ConfigError, match=field):
            PinholeFrustum(hfov=1.0, vfov=1.0, far=5.0, **{field: bad})
    with pytest.raises(ConfigError, match="side_shrink: 2.0 closes the field of view"):
        PinholeFrustum(hfov=1.0, vfov=1.0, far=5.0, side_shrink=2.0)
    with pytest.raises(ConfigError, match="near: 6.0 is beyond the far face"):
        PinholeFrustum(hfov=1.0, vfov=1.0, far=5.0, near=6.0)


def test_asymmetric_intrinsics_match_pixel_projection(rng):
    fx, fy, W, H, cx, cy = 200.0, 180.0, 320, 240, 100.0, 150.0
    fr = PinholeFrustum.from_intrinsics(fx, fy, W, H, far=5.0, cx=cx, cy=cy)
    p = points_around_camera(rng, 20_000, fr.far)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = fx * p[:, 0] / p[:, 2] + cx
        v = fy * p[:, 1] / p[:, 2] + cy
    inside = (p[:, 2] > 0) & (u >= 0) & (u <= W) & (v >= 0) & (v <= H) & (p[:, 2] <= 5.0)
    assert inside.sum() > 500
    np.testing.assert_array_equal(points_in_frustum(np.eye(3), np.zeros(3), fr, p), inside)
    # The drawn corners project onto the image corners at the far depth.
    corners = frustum_corners(np.eye(3), np.zeros(3), fr)
    np.testing.assert_allclose(corners[0], 0.0)
    uv = np.c_[fx * corners[1:, 0] / corners[1:, 2] + cx, fy * corners[1:, 1] / corners[1:, 2] + cy]
    np.testing.assert_allclose(uv, [[0, 0], [W, 0], [W, H], [0, H]], atol=1e-9)
    np.testing.assert_allclose(corners[1:, 2], 5.0)


def test_intrinsics_equal_angles_when_centred():
    fr_i = PinholeFrustum.from_intrinsics(fx=160, fy=160, width=320, height=240, far=4.0)
    fr_a = PinholeFrustum(hfov=2 * np.arctan(1.0), vfov=2 * np.arctan(120 / 160), far=4.0)
    for a, b in zip(fr_i.optical_halfspaces(), fr_a.optical_halfspaces(), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_range_kind_stays_inside_the_range_sphere(rng):
    for fr in (
        PinholeFrustum(hfov=np.radians(100), vfov=np.radians(70), far=6.0, far_kind="range"),
        PinholeFrustum.from_intrinsics(150, 150, 320, 240, 6.0, far_kind="range", cx=60, cy=200),
    ):
        corners = frustum_corners(np.eye(3), np.zeros(3), fr)
        dist = np.linalg.norm(corners[1:], axis=1)
        assert np.all(dist <= fr.far + 1e-9)
        assert dist.max() == pytest.approx(fr.far, rel=1e-12), "inner approximation not tight"
        p = points_around_camera(rng, 20_000, fr.far)
        inside = points_in_frustum(np.eye(3), np.zeros(3), fr, p)
        assert inside.sum() > 100 and np.all(np.linalg.norm(p[inside], axis=1) <= fr.far)


@pytest.mark.parametrize("face", range(5))
def test_ellipsoids_just_inside_or_outside_each_face(rng, face):
    fr = PinholeFrustum(hfov=np.radians(80), vfov=np.radians(60), far=5.0)
    R = camera_rotation(yaw_matrix(0.7), np.radians(15))
    o = np.array([1.0, 2.0, 1.5])
    A, b = frustum_halfspaces(R, o, fr)
    U = Rotation.random(random_state=face).as_matrix()
    _, M = ellipsoid_from_axes(np.zeros(3), U, [0.3, 0.2, 0.1])
    start = o + R @ [0, 0, 2.5]  # well inside
    for delta in (0.02, -0.02):
        # Slide along the face normal until that face's margin is delta (closed form: the
        # margin falls linearly with the shift), then judge containment by surface sampling.
        m0 = halfspace_margins(start, M, A, b)[face]
        c = start + (m0 - delta) * A[face]
        margins = halfspace_margins(c, M, A, b)
        assert margins[face] == pytest.approx(delta, abs=1e-12)
        assert np.delete(margins, face).min() > 0.05, "test setup must only stress one face"
        pts = surface_points(c, M, 20_000, rng)
        seen = points_in_frustum(R, o, fr, pts)
        margin = ellipsoid_in_frustum_margin(c, M, R, o, fr)
        assert margin == pytest.approx(delta, abs=1e-12)
        assert seen.all() == (delta > 0), f"face {face}: margin {margin} vs sampling"


def test_batched_poses_and_ellipsoids(rng):
    fr = PinholeFrustum(hfov=1.2, vfov=0.9, far=4.0)
    n = 8
    Rs = np.array([random_pose(rng)[0] for _ in range(n)])
    os_ = rng.uniform(-1, 1, (n, 3))
    C = os_ + np.einsum("nij,j->ni", Rs, [0, 0, 2.0]) + rng.normal(0, 0.3, (n, 3))
    Ms = np.array(
        [ellipsoid_from_axes(np.zeros(3), Rs[i], rng.uniform(0.1, 0.5, 3))[1] for i in range(n)]
    )
    A, b = frustum_halfspaces(Rs, os_, fr)
    assert A.shape == (n, 5, 3) and b.shape == (n, 5)
    batched = ellipsoid_in_frustum_margin(C, Ms, Rs, os_, fr)
    for i in range(n):
        assert batched[i] == pytest.approx(
            ellipsoid_in_frustum_margin(C[i], Ms[i], Rs[i], os_[i], fr), abs=1e-12
        )
    corners = frustum_corners(Rs, os_, fr)
    np.testing.assert_allclose(corners[3], frustum_corners(Rs[3], os_[3], fr), atol=1e-12)


def test_casadi_twins_match_numpy(rng):
    fr = PinholeFrustum.from_intrinsics(170, 160, 320, 240, 6.0, far_kind="range", cx=150, cy=130)
    yaw, pitch = ca.SX.sym("yaw"), ca.SX.sym("pitch")
    origin, c, M = ca.SX.sym("o", 3), ca.SX.sym("c", 3), ca.SX.sym("M", 3, 3)
    R = camera_rotation(yaw_matrix(yaw), pitch)
    A, b = frustum_halfspaces(R, origin, fr)
    f = ca.Function(
        "f", [yaw, pitch, origin, c, M], [A, b, ellipsoid_in_frustum_margin(c, M, R, origin, fr)]
    )
    for _ in range(20):
        y, p = rng.uniform(-3, 3), rng.uniform(-0.5, 0.5)
        ov = rng.uniform(-3, 3, 3)
        Rv = camera_rotation(yaw_matrix(y), p)
        cv = ov + Rv @ [0, 0, 3.0] + rng.normal(0, 1, 3)
        _, Mv = ellipsoid_from_axes(
            cv,
            Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix(),
            rng.uniform(0.1, 1, 3),
        )
        A_s, b_s, m_s = f(y, p, ov, cv, Mv)
        A_n, b_n = frustum_halfspaces(Rv, ov, fr)
        np.testing.assert_allclose(np.array(A_s), A_n, atol=1e-9)
        np.testing.assert_allclose(np.array(b_s).ravel(), b_n, atol=1e-9)
        np.testing.assert_allclose(
            float(m_s), ellipsoid_in_frustum_margin(cv, Mv, Rv, ov, fr), atol=1e-9
        )


def test_side_plane_angles_are_the_unit_normals_of_the_side_halfspaces():
    """The certificate's (sin, cos) of the side planes agree with optical_halfspaces' normals, with
    and without an observed field of view's shrink."""
    for shrink in (0.0, 0.05):
        fr = PinholeFrustum(np.radians(90), np.radians(50), 6.0, side_shrink=shrink)
        sin_h, cos_h, sin_v, cos_v = fr.side_plane_angles()
        N, _ = fr.optical_halfspaces()
        np.testing.assert_allclose(N[0], [cos_h, 0.0, -sin_h], atol=1e-12)
        np.testing.assert_allclose(N[3], [0.0, -cos_v, -sin_v], atol=1e-12)
