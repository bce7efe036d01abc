"""RK4: measured convergence order against an independent high-accuracy integrator."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from secure3d.dynamics import make_model, rk4_step, rollout
from secure3d.errors import ConfigError


def _error(model, x0, u, T, dt):
    X = rollout(model.f, x0, np.tile(u, (round(T / dt), 1)), dt)
    ref = solve_ivp(lambda t, x: model.f(x, u), (0, T), x0, method="DOP853", rtol=1e-13, atol=1e-13)
    return float(np.abs(X[-1] - ref.y[:, -1]).max())


@pytest.mark.parametrize(
    ("name", "x0", "u"),
    [
        # A tumbling quadrotor: thrust and body rates about all axes (nonlinear in q).
        ("quadrotor", [0, 0, 0, 1, -1, 0.5, 1, 0, 0, 0], [12.0, 2.0, -1.5, 1.0]),
        # A diff drive speeding up while turning faster (trigonometric in theta).
        ("diff_drive", [0, 0, 0.3, 1.0, 0.5], [0.8, 1.5]),
    ],
)
def test_rk4_is_fourth_order(name, x0, u):
    model = make_model(name)
    x0, u = np.array(x0, dtype=float), np.array(u, dtype=float)
    errors = [_error(model, x0, u, 2.0, dt) for dt in (0.1, 0.05, 0.025)]
    ratios = [errors[i] / errors[i + 1] for i in range(2)]
    for r in ratios:
        assert 13.0 < r < 19.0, f"{name}: error ratios {ratios} (errors {errors}), expected ~16"
    order = math.log2(errors[1] / errors[2])
    assert abs(order - 4.0) < 0.25, f"{name}: measured order {order:.3f}"


def test_batched_step_equals_rows(rng):
    model = make_model("diff_drive")
    X = rng.normal(size=(8, 5))
    U = rng.normal(size=(8, 2))
    batch = rk4_step(model.f, X, U, 0.03)
    for i in range(8):
        np.testing.assert_allclose(batch[i], rk4_step(model.f, X[i], U[i], 0.03), atol=1e-14)


def test_rollout_shapes_and_projection():
    model = make_model("quadrotor")
    x0 = model.initial_state((0, 0, 0))
    U = np.tile([10.0, 3.0, 0.0, 0.0], (20, 1))
    X = rollout(model.f, x0, U, 0.05, project=model.project_state)
    assert X.shape == (21, 10)
    np.testing.assert_allclose(X[0], x0)
    np.testing.assert_allclose(np.linalg.norm(X[:, 6:10], axis=1), 1.0, atol=1e-14)
    batch = rollout(model.f, np.stack([x0, x0]), np.tile(U[:, None], (1, 2, 1)), 0.05)
    assert batch.shape == (21, 2, 10)
    with pytest.raises(ValueError):
        rollout(model.f, x0, U[:, None], 0.05)


@pytest.mark.parametrize("dt", [0.0, -0.1, float("nan"), float("inf")])
def test_rollout_rejects_bad_step(dt):
    model = make_model("point_mass")
    with pytest.raises(ConfigError, match="dt"):
        rollout(model.f, np.zeros(7), np.zeros((3, 4)), dt)
