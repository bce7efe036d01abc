"""Vehicle models: CasADi and numpy agree, batch equals single, physics and camera conventions."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest

from secure3d.dynamics import CameraMount, DiffDrive, PointMass, Quadrotor, make_model
from secure3d.dynamics.integrate import rk4_step
from secure3d.reactive.sampling import sample_hold_controls, sample_states

MODELS = ["point_mass", "quadrotor", "diff_drive"]
MOUNT = CameraMount(pitch=0.3, offset=(0.1, -0.05, 0.08))


def _random(model, rng, n=50):
    X = sample_states(model, n, rng)
    # Perturb beyond the sampler's structure (e.g. non-level, non-unit quaternions for f).
    X = X + 0.1 * rng.normal(size=X.shape)
    U = sample_hold_controls(model, n, rng)
    return X, U


def _casadi_fn(model, method):
    x = ca.SX.sym("x", model.nx)
    u = ca.SX.sym("u", model.nu)
    if method in ("f", "path_constraints"):
        out = getattr(model, method)(x, u)
        return ca.Function(method, [x, u], [out])
    if method == "camera_pose":
        R, o = model.camera_pose(x)
        return ca.Function(method, [x], [R, o])
    return ca.Function(method, [x], [getattr(model, method)(x)])


@pytest.mark.parametrize("name", MODELS)
def test_casadi_and_numpy_dynamics_agree(name, rng):
    model = make_model(name, mount=MOUNT)
    X, U = _random(model, rng)
    f_sym, g_sym = _casadi_fn(model, "f"), _casadi_fn(model, "path_constraints")
    for x, u in zip(X, U, strict=True):
        np.testing.assert_allclose(
            np.array(f_sym(x, u)).ravel(),
            model.f(x, u),
            rtol=1e-12,
            atol=1e-12,
            err_msg=f"{name} f",
        )
        g = model.path_constraints(x, u)
        np.testing.assert_allclose(
            np.array(g_sym(x, u)).ravel(), g, atol=1e-12, err_msg=f"{name} g"
        )


@pytest.mark.parametrize("name", MODELS)
def test_casadi_and_numpy_geometry_agree(name, rng):
    model = make_model(name, mount=MOUNT)
    X, _ = _random(model, rng)
    if name == "quadrotor":
        X[:, 6:10] /= np.linalg.norm(X[:, 6:10], axis=1, keepdims=True)  # numpy normalises q
    pos, vel, rot = (_casadi_fn(model, m) for m in ("position", "velocity", "body_rotation"))
    cam = _casadi_fn(model, "camera_pose")
    for x in X:
        np.testing.assert_allclose(np.array(pos(x)).ravel(), model.position(x), atol=1e-12)
        np.testing.assert_allclose(np.array(vel(x)).ravel(), model.velocity(x), atol=1e-12)
        np.testing.assert_allclose(np.array(rot(x)), model.body_rotation(x), atol=1e-12)
        R_sym, o_sym = cam(x)
        R, o = model.camera_pose(x)
        np.testing.assert_allclose(np.array(R_sym), R, atol=1e-12, err_msg=f"{name} camera R")
        np.testing.assert_allclose(
            np.array(o_sym).ravel(), o, atol=1e-12, err_msg=f"{name} camera o"
        )


@pytest.mark.parametrize("name", MODELS)
def test_batch_equals_single(name, rng):
    model = make_model(name, mount=MOUNT)
    X, U = _random(model, rng, 20)
    F = model.f_batch(X, U)
    S = model.step_batch(X, U, 0.02)
    R, O = model.camera_pose(X)
    for i in range(len(X)):
        np.testing.assert_allclose(F[i], model.f(X[i], U[i]), atol=1e-12)
        np.testing.assert_allclose(S[i], model.step(X[i], U[i], 0.02), atol=1e-12)
        Ri, Oi = model.camera_pose(X[i])
        np.testing.assert_allclose(R[i], Ri, atol=1e-12)
        np.testing.assert_allclose(O[i], Oi, atol=1e-12)
    assert model.path_constraints(X, U).shape[0] == len(X)


@pytest.mark.parametrize("name", MODELS)
def test_single_state_fast_paths_give_the_batch_values_bit_for_bit(name, rng):
    """One state's f (its components as floats) and body rotation (a quaternion's entries written
    out) are the batch path's values exactly, not just to rounding: the simulator steps one state
    at a time and its flights are pinned bit for bit (tests/test_golden_outputs.py)."""
    model = make_model(name, mount=MOUNT)
    X, U = _random(model, rng, 200)
    F, R = model.f_batch(X, U), model.body_rotation(X)
    for i in range(len(X)):
        np.testing.assert_array_equal(model.f(X[i], U[i]), F[i])
        np.testing.assert_array_equal(model.body_rotation(X[i]), R[i])


@pytest.mark.parametrize("name", MODELS)
def test_rotations_are_proper(name, rng):
    model = make_model(name, mount=MOUNT)
    X = sample_states(model, 30, rng)
    R = model.body_rotation(X)
    Rc, _ = model.camera_pose(X)
    for A in (R, Rc):
        np.testing.assert_allclose(
            np.swapaxes(A, 1, 2) @ A, np.broadcast_to(np.eye(3), A.shape), atol=1e-12
        )
        np.testing.assert_allclose(np.linalg.det(A), 1.0, atol=1e-12)


def test_camera_conventions_level_and_pitched():
    """Optical z forward, x right, y down; positive pitch looks down; offset in the body frame."""
    model = make_model("point_mass", mount=CameraMount(pitch=0.0, offset=(0.5, 0.0, 0.1)))
    x = model.initial_state((1.0, 2.0, 3.0), yaw=math.pi / 2)  # facing world +y
    R, o = model.camera_pose(x)
    np.testing.assert_allclose(R[:, 2], [0, 1, 0], atol=1e-12, err_msg="optical z = heading")
    np.testing.assert_allclose(
        R[:, 0], [1, 0, 0], atol=1e-12, err_msg="optical x = right of heading"
    )
    np.testing.assert_allclose(R[:, 1], [0, 0, -1], atol=1e-12, err_msg="optical y = down")
    np.testing.assert_allclose(o, [1.0, 2.5, 3.1], atol=1e-12, err_msg="offset rotates with yaw")
    pitched = make_model("point_mass", mount=CameraMount(pitch=0.4))
    R, _ = pitched.camera_pose(pitched.initial_state((0, 0, 0)))
    np.testing.assert_allclose(R[:, 2], [math.cos(0.4), 0, -math.sin(0.4)], atol=1e-12)


def test_quadrotor_camera_tilts_with_the_body():
    """Pitching the quadrotor nose-down (to accelerate forward) points a level camera down."""
    model = make_model("quadrotor")
    x = model.initial_state((0, 0, 0))
    a = 0.5
    x[6:10] = [math.cos(a / 2), 0.0, math.sin(a / 2), 0.0]  # rotation about body y: nose down
    R, _ = model.camera_pose(x)
    np.testing.assert_allclose(R[:, 2], [math.cos(a), 0, -math.sin(a)], atol=1e-12)
    np.testing.assert_allclose(model.thrust_axis(x), [math.sin(a), 0, math.cos(a)], atol=1e-12)
    # ... and the thrust then accelerates it forward.
    xdot = model.f(x, model.nominal_control(x))
    assert xdot[3] > 0


def test_quadrotor_physics():
    model = make_model("quadrotor")
    hover = model.rest_state((1, 2, 3), yaw=0.7)
    np.testing.assert_allclose(model.f(hover, model.nominal_control(hover)), 0.0, atol=1e-12)
    # qdot is orthogonal to q: the flow keeps |q| = 1.
    rng = np.random.default_rng(1)
    X = sample_states(model, 20, rng)
    U = sample_hold_controls(model, 20, rng)
    F = model.f_batch(X, U)
    np.testing.assert_allclose(np.einsum("ij,ij->i", X[:, 6:10], F[:, 6:10]), 0.0, atol=1e-12)
    # A body yaw rate turns the heading at that rate.
    x, u = hover.copy(), np.array([model.limits.gravity, 0.0, 0.0, 1.0])
    for _ in range(50):
        x = model.step(x, u, 0.01)
    assert math.isclose(float(model.yaw(x)), 0.7 + 0.5, abs_tol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(x[6:10]), 1.0, atol=1e-12)


def test_point_mass_and_diff_drive_physics():
    pm = make_model("point_mass")
    x = pm.initial_state((0, 0, 0), (1, 2, 3), 0.2)
    np.testing.assert_allclose(pm.f(x, [0.5, 0, 0, 0.1]), [1, 2, 3, 0.5, 0, 0, 0.1], atol=1e-15)
    assert math.isclose(float(pm.speed(x)), math.sqrt(14))
    dd = make_model("diff_drive", height=0.3)
    x = dd.initial_state((1, 1, 5), (0, 2, 0), math.pi / 2)
    np.testing.assert_allclose(x, [1, 1, math.pi / 2, 2, 0], atol=1e-15)
    np.testing.assert_allclose(dd.position(x), [1, 1, 0.3], atol=1e-15)
    np.testing.assert_allclose(dd.velocity(x), [0, 2, 0], atol=1e-12)
    # No sideways motion: only the component along the heading is kept.
    assert dd.initial_state((0, 0, 0), (1.0, 3.0, 2.0), 0.0)[3] == 1.0
    # Constant turn: an arc of radius v / omega.
    x = np.array([0.0, 0.0, 0.0, 1.0, 0.5])
    for _ in range(100):
        x = dd.step(x, np.zeros(2), 0.01)
    np.testing.assert_allclose(x[:2], [2 * math.sin(0.5), 2 * (1 - math.cos(0.5))], atol=1e-10)


def test_bounds_and_constraints_reflect_limits():
    pm = make_model("point_mass", max_accel=3.0, max_speed=5.0, max_yaw_rate=1.5)
    np.testing.assert_array_equal(pm.u_hi, [3, 3, 3, 1.5])
    np.testing.assert_array_equal(pm.x_hi[3:6], [5, 5, 5])
    assert np.isinf(pm.x_lo[:3]).all()
    assert pm.path_constraints(np.zeros(7), np.zeros(4)).shape == (2,)
    box = make_model("point_mass", accel_norm="box")
    assert box.path_constraints(np.zeros(7), np.zeros(4)).shape == (1,)
    g = pm.path_constraints(pm.initial_state((0, 0, 0), (3, 4, 0)), np.array([3.0, 0, 0, 0]))
    np.testing.assert_allclose(g, [25 - 25, 9 - 9], atol=1e-12)
    q = make_model("quadrotor")
    assert q.u_lo[0] == q.limits.thrust_min and q.u_hi[0] == q.limits.thrust_max
    tilted = q.initial_state((0, 0, 0))
    t = q.limits.max_tilt + 0.1
    tilted[6:10] = [math.cos(t / 2), math.sin(t / 2), 0, 0]
    assert q.path_constraints(tilted, q.nominal_control(tilted))[1] > 0, "tilt beyond max_tilt"
    dd = make_model("diff_drive")
    assert dd.path_constraints(np.zeros(5), np.zeros(2)).shape == (0,)
    x = ca.SX.sym("x", 5)
    assert dd.path_constraints(x, ca.SX.sym("u", 2)).shape == (0, 1)


def test_types_and_names():
    for name, cls in (
        ("point_mass", PointMass),
        ("quadrotor", Quadrotor),
        ("diff_drive", DiffDrive),
    ):
        model = make_model(name)
        assert isinstance(model, cls) and model.name == name
        assert model.nx == len(model.state_names) and model.nu == len(model.control_names)
        assert model.u_lo.shape == (model.nu,) and model.x_lo.shape == (model.nx,)
        with pytest.raises(ValueError):
            model.u_lo[0] = 0.0  # read-only


def test_rk4_step_works_symbolically():
    model = make_model("quadrotor")
    x, u = ca.SX.sym("x", 10), ca.SX.sym("u", 4)
    step = ca.Function("step", [x, u], [rk4_step(model.f, x, u, 0.05)])
    rng = np.random.default_rng(2)
    X = sample_states(model, 5, rng)
    U = sample_hold_controls(model, 5, rng)
    for xi, ui in zip(X, U, strict=True):
        np.testing.assert_allclose(
            np.array(step(xi, ui)).ravel(), rk4_step(model.f, xi, ui, 0.05), atol=1e-12
        )


def test_batched_initial_states_equal_the_single_ones_bit_for_bit():
    """Every model's initial_states(N rows) is its initial_state row by row, to the last bit,
    and refuses rows that do not match or are not finite."""
    from secure3d.errors import ConfigError

    rng = np.random.default_rng(3)
    p, v = rng.uniform(-5, 5, (50, 3)), rng.uniform(-3, 3, (50, 3))
    yaw = rng.uniform(-7, 7, 50)
    for name in ("point_mass", "quadrotor", "diff_drive"):
        model = make_model(name)
        want = np.stack([model.initial_state(a, b, c) for a, b, c in zip(p, v, yaw, strict=True)])
        assert np.array_equal(model.initial_states(p, v, yaw), want), name
        assert model.initial_states(p[:0], v[:0], yaw[:0]).shape == (0, model.nx)
    quad = make_model("quadrotor")
    with pytest.raises(ConfigError, match="positions"):
        quad.initial_states(p, v[:3], yaw)
    bad = p.copy()
    bad[4, 1] = np.nan
    with pytest.raises(ConfigError, match="finite"):
        quad.initial_states(bad, v, yaw)
