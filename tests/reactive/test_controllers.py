"""Reactive controllers: braking for every model, the MPC against its CasADi solve."""

from __future__ import annotations

import math

import numpy as np
import pytest

from secure3d.dynamics import make_model
from secure3d.errors import ConfigError
from secure3d.reactive.controllers import (
    BrakingController,
    MPCReactiveController,
    MPCWeights,
    QuadrotorBrakingGains,
    obstacle_direction,
)
from secure3d.reactive.sampling import sample_hold_controls, sample_obstacles, sample_states

DT = 0.01


@pytest.mark.parametrize("norm", ["ball", "box"])
def test_point_mass_brakes_along_a_straight_segment(norm, rng):
    model = make_model("point_mass", accel_norm=norm)
    ctrl = BrakingController(model)
    X0 = sample_states(model, 300, rng)
    t, X = ctrl.rollout_batch(X0, dt=DT)
    v0 = X0[:, 3:6]
    s0 = np.linalg.norm(v0, axis=1)
    assert ctrl.at_rest(X[:, -1]).all()
    travel = X[:, -1, :3] - X0[:, :3]
    # Continuous stopping distance s^2 / (2 a); the capped last step adds at most a dt^2 / 8.
    a = model.limits.max_accel
    np.testing.assert_allclose(
        np.linalg.norm(travel, axis=1), s0**2 / (2 * a), atol=a * DT**2 / 8 + 1e-12
    )
    # Straight: the velocity stays a non-negative multiple of v0 (no chattering through zero).
    along = np.einsum("ntj,nj->nt", X[:, :, 3:6], v0)
    cross = np.linalg.norm(np.cross(X[:, :, 3:6], v0[:, None, :]), axis=2)
    assert np.all(along >= -1e-12) and np.all(cross <= 1e-9)
    U = ctrl.control_batch(X0, DT)
    assert np.all(U[:, :3] >= model.u_lo[:3] - 1e-12) and np.all(U[:, :3] <= model.u_hi[:3] + 1e-12)
    assert np.all(np.linalg.norm(U[:, :3], axis=1) <= a + 1e-12)
    assert t.shape == (X.shape[1],) and math.isclose(t[1] - t[0], DT)


def test_quadrotor_braking_respects_limits_and_settles(rng):
    model = make_model("quadrotor")
    ctrl = BrakingController(model)
    X0 = sample_states(model, 400, rng)
    t, X = ctrl.rollout_batch(X0, dt=DT)
    assert t[-1] < ctrl.default_t_max(), "every manoeuvre should settle before the horizon"
    end = X[:, -1]
    assert np.all(np.linalg.norm(end[:, 3:6], axis=1) < 1e-3)
    np.testing.assert_allclose(model.thrust_axis(end)[:, 2], 1.0, atol=1e-5, err_msg="ends level")
    U = np.concatenate([ctrl.control_batch(X[:, k], DT) for k in range(0, X.shape[1], 10)])
    lim = model.limits
    assert np.all(U[:, 0] >= lim.thrust_min - 1e-12) and np.all(U[:, 0] <= lim.thrust_max + 1e-12)
    assert np.all(np.abs(U[:, 1:3]) <= lim.max_rate + 1e-12) and np.all(U[:, 3] == 0)
    # It does brake: the stopping distance of a level quadrotor is close to s^2 / (2 a_b).
    x0 = model.initial_state((0, 0, 0), (4.0, 0, 0))
    _, Xs = ctrl.rollout(x0, dt=DT)
    ideal = 16 / (2 * ctrl.deceleration)
    assert ideal < Xs[-1, 0] < ideal + 1.0, (Xs[-1, 0], ideal)


def test_diff_drive_braking(rng):
    model = make_model("diff_drive")
    ctrl = BrakingController(model)
    X0 = sample_states(model, 300, rng)
    _, X = ctrl.rollout_batch(X0, dt=DT)
    assert ctrl.at_rest(X[:, -1]).all()
    lim = model.limits
    np.testing.assert_allclose(
        np.abs(X[:, -1, 2] - X0[:, 2]),
        X0[:, 4] ** 2 / (2 * lim.max_ang_accel),
        atol=lim.max_ang_accel * DT**2 / 8,
    )
    assert np.all(X[:, :, 3] * np.sign(X0[:, 3])[:, None] >= -1e-12), "no reversing"
    U = ctrl.control_batch(X0, DT)
    assert np.all(U >= model.u_lo - 1e-12) and np.all(U <= model.u_hi + 1e-12)


@pytest.mark.parametrize("name", ["point_mass", "quadrotor", "diff_drive"])
def test_latency_holds_the_given_control(name, rng):
    model = make_model(name)
    ctrl = BrakingController(model, latency=0.25)
    X0 = sample_states(model, 5, rng)
    U = sample_hold_controls(model, 5, rng)
    _, X = ctrl.rollout_batch(X0, dt=DT, u_hold=U)
    x = X0.copy()
    for _ in range(25):
        x = model.step_batch(x, U, DT)
    np.testing.assert_allclose(X[:, 25], x, atol=1e-12)
    _, X_default = ctrl.rollout_batch(X0[:1], dt=DT)
    x = X0[:1]
    for _ in range(25):
        x = model.step_batch(x, model.nominal_control(x), DT)
    np.testing.assert_allclose(X_default[:, 25], x, atol=1e-12)


def test_batch_rollout_equals_single_rollouts(rng):
    model = make_model("quadrotor")
    ctrl = BrakingController(model)
    X0 = sample_states(model, 4, rng)
    _, X = ctrl.rollout_batch(X0, dt=DT)
    for i in range(4):
        _, Xi = ctrl.rollout(X0[i], dt=DT)
        np.testing.assert_allclose(X[i, : len(Xi)], Xi, atol=1e-12)
        # Once at rest (speed < 1e-3 m/s, decaying) it moves less than a millimetre further.
        drift = np.linalg.norm(X[i, len(Xi) :, :3] - Xi[-1, :3], axis=1)
        assert drift.max(initial=0.0) < 1e-3


@pytest.mark.parametrize("norm", ["ball", "box"])
def test_mpc_batched_solver_matches_casadi(norm, rng):
    model = make_model("point_mass", accel_norm=norm)
    mpc = MPCReactiveController(model)
    X = sample_states(model, 6, rng)
    lo, hi = sample_obstacles(model, X, rng)
    takeover = X[:, :3] + 0.5 * rng.normal(size=(6, 3))
    n = obstacle_direction(X[:, :3], lo, hi, np.zeros((6, 3)))
    U, _ = mpc.solve_batch(X, takeover, n)
    for i in range(6):
        mpc._warm = None
        np.testing.assert_allclose(
            mpc.solve(X[i], takeover[i], n[i]), U[i], atol=2e-5, err_msg=f"state {i}"
        )
        u = mpc.control(X[i], obstacle=np.stack([lo[i], hi[i]]), takeover_point=takeover[i])
        np.testing.assert_allclose(u[:3], U[i, 0], atol=2e-5)
    a = model.limits.max_accel
    if norm == "ball":
        assert np.linalg.norm(U, axis=2).max() <= a + 1e-9
    else:
        assert np.abs(U).max() <= a + 1e-12


def test_mpc_stops_and_settles_away_from_the_obstacle():
    model = make_model("point_mass")
    mpc = MPCReactiveController(model)
    x0 = model.initial_state((0, 0, 0), (4.0, 0, 0))
    lo, hi = np.array([3.0, -1, -1]), np.array([4.0, 1, 1])
    t, X = mpc.rollout(x0, np.stack([lo, hi]))
    assert X[:, 0].max() < 3.0 - model.body_radius, "stopped short of the obstacle"
    offset = mpc.weights.repulsion / (2 * mpc.weights.drift)
    np.testing.assert_allclose(
        X[-1, :3], [-offset, 0, 0], atol=5e-3, err_msg="settles away from it"
    )
    assert np.linalg.norm(X[-1, 3:6]) < 1e-3 and t[-1] < mpc.default_t_max()
    _, X_lohi = mpc.rollout(x0, obstacle_lo=lo, obstacle_hi=hi, takeover_point=x0[:3])
    np.testing.assert_array_equal(X_lohi, X)


def test_controller_configuration_errors():
    with pytest.raises(ConfigError, match="point_mass"):
        MPCReactiveController(make_model("quadrotor"))
    with pytest.raises(ConfigError, match="horizon"):
        MPCReactiveController(make_model("point_mass"), horizon=1)
    with pytest.raises(ConfigError, match="latency"):
        BrakingController(make_model("point_mass"), latency=-1)
    with pytest.raises(ConfigError, match="attitude_gain"):
        QuadrotorBrakingGains(attitude_gain=0)
    with pytest.raises(ConfigError, match="drift"):
        MPCWeights(drift=float("nan"))
    with pytest.raises(ConfigError, match="obstacle"):
        MPCReactiveController(make_model("point_mass")).control(np.zeros(7))
