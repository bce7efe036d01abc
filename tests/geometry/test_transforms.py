"""Rotations and quaternions, cross-checked against scipy's Rotation (independent code)."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from secure3d.errors import GeometryError
from secure3d.geometry.transforms import (
    BODY_FROM_OPTICAL,
    camera_rotation,
    check_rotation,
    matrix_to_quat,
    pitch_matrix,
    quat_from_axis_angle,
    quat_from_yaw,
    quat_multiply,
    quat_to_matrix,
    yaw_matrix,
)


def _scipy_quat(q_wxyz: np.ndarray) -> Rotation:
    return Rotation.from_quat(np.roll(q_wxyz, -1, axis=-1))


def test_yaw_and_pitch_match_scipy_euler(rng):
    angles = rng.uniform(-np.pi, np.pi, 50)
    np.testing.assert_allclose(
        yaw_matrix(angles), Rotation.from_euler("z", angles[:, None]).as_matrix(), atol=1e-12
    )
    np.testing.assert_allclose(
        pitch_matrix(angles), Rotation.from_euler("y", angles[:, None]).as_matrix(), atol=1e-12
    )


def test_positive_pitch_tilts_nose_down():
    nose = pitch_matrix(0.3) @ np.array([1.0, 0.0, 0.0])
    assert nose[2] < -0.29, f"positive pitch must point body x below the horizon, got {nose}"


def test_quat_to_matrix_matches_scipy_and_normalises(rng):
    q = rng.standard_normal((100, 4)) * rng.uniform(0.1, 10, (100, 1))  # deliberately not unit
    np.testing.assert_allclose(quat_to_matrix(q), _scipy_quat(q).as_matrix(), atol=1e-12)


def test_matrix_to_quat_roundtrip_including_half_turns(rng):
    rots = Rotation.random(200, random_state=1)
    axes = rng.standard_normal((20, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    half_turns = Rotation.from_rotvec(np.pi * axes)  # the cases where w ~ 0 and Shepperd matters
    for r in (rots, half_turns, Rotation.identity()):
        q = matrix_to_quat(r.as_matrix())
        assert np.all(q[..., 0] >= 0)
        np.testing.assert_allclose(np.linalg.norm(q, axis=-1), 1.0, atol=1e-12)
        np.testing.assert_allclose(
            _scipy_quat(q).as_matrix(), r.as_matrix(), atol=1e-12, err_msg="R(q(R)) != R"
        )


def test_quat_multiply_composes_rotations(rng):
    q1, q2 = rng.standard_normal((2, 50, 4))
    q1 /= np.linalg.norm(q1, axis=-1, keepdims=True)
    q2 /= np.linalg.norm(q2, axis=-1, keepdims=True)
    expected = (_scipy_quat(q1) * _scipy_quat(q2)).as_matrix()
    np.testing.assert_allclose(quat_to_matrix(quat_multiply(q1, q2)), expected, atol=1e-12)


def test_quat_from_yaw_and_axis_angle(rng):
    yaw = rng.uniform(-4, 4, 30)
    np.testing.assert_allclose(quat_to_matrix(quat_from_yaw(yaw)), yaw_matrix(yaw), atol=1e-12)
    axis = rng.standard_normal((30, 3)) * 3
    angle = rng.uniform(-4, 4, 30)
    rotvec = axis / np.linalg.norm(axis, axis=1, keepdims=True) * angle[:, None]
    np.testing.assert_allclose(
        quat_to_matrix(quat_from_axis_angle(axis, angle)),
        Rotation.from_rotvec(rotvec).as_matrix(),
        atol=1e-12,
    )
    with pytest.raises(GeometryError, match="axis"):
        quat_from_axis_angle([0, 0, 0], 1.0)


def test_camera_looks_along_body_x_with_image_down_toward_ground():
    # Body yawed to face world +y: the optical axis must point along +y, image-down along -z,
    # image-right along +x (right of a viewer facing +y in a z-up world).
    R = camera_rotation(yaw_matrix(np.pi / 2), 0.0)
    np.testing.assert_allclose(R @ [0, 0, 1], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(R @ [0, 1, 0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(R @ [1, 0, 0], [1, 0, 0], atol=1e-12)
    assert np.linalg.det(BODY_FROM_OPTICAL) == pytest.approx(1.0)
    # A camera pitched down by 30 degrees looks 30 degrees below the horizon.
    axis = camera_rotation(np.eye(3), np.radians(30)) @ [0, 0, 1]
    np.testing.assert_allclose(axis, [np.cos(np.radians(30)), 0, -np.sin(np.radians(30))])


def test_check_rotation_rejects_and_cleans(rng):
    R = Rotation.random(random_state=3).as_matrix()
    cleaned = check_rotation(R + 1e-8 * rng.standard_normal((3, 3)))
    np.testing.assert_allclose(cleaned.T @ cleaned, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(cleaned, R, atol=1e-7)
    with pytest.raises(GeometryError, match="orthonormal"):
        check_rotation(1.01 * R)
    with pytest.raises(GeometryError, match="reflection"):
        check_rotation(-R)
    with pytest.raises(GeometryError, match="shape"):
        check_rotation(np.eye(4))
    with pytest.raises(GeometryError, match="finite"):
        check_rotation(np.full((3, 3), np.nan))


def test_casadi_twins_match_numpy(rng):
    yaw, pitch = ca.SX.sym("yaw"), ca.SX.sym("pitch")
    q = ca.SX.sym("q", 4)
    Rb = ca.SX.sym("Rb", 3, 3)
    f = ca.Function(
        "f",
        [yaw, pitch, q, Rb],
        [yaw_matrix(yaw), pitch_matrix(pitch), quat_to_matrix(q), camera_rotation(Rb, pitch)],
    )
    for _ in range(20):
        y, p = rng.uniform(-np.pi, np.pi, 2)
        qv = rng.standard_normal(4)
        qv /= np.linalg.norm(qv)
        Rv = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
        out = [np.array(o) for o in f(y, p, qv, Rv)]
        expected = [yaw_matrix(y), pitch_matrix(p), quat_to_matrix(qv), camera_rotation(Rv, p)]
        for got, want in zip(out, expected, strict=True):
            np.testing.assert_allclose(got, want, atol=1e-9)
