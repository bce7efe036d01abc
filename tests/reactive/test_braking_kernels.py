"""The compiled braking manoeuvres (secure3d.dynamics._braking_kernels) against the generic numpy
loop they replace: the same number of steps and the same states to rounding, on random states of
every model, with and without latency and held controls."""

from __future__ import annotations

import math

import numpy as np
import pytest

from secure3d.dynamics import make_model
from secure3d.reactive.controllers import BrakingController, QuadrotorBrakingGains


def _both(controller, X0, dt, u_hold=None, t_max=None):
    """(compiled, generic) trajectories (N, T, nx) of the same batch."""
    _, fast = controller.rollout_batch(X0, dt=dt, u_hold=u_hold, t_max=t_max)
    model = controller.model
    X = model.project_state(np.array(X0, dtype=float, ndmin=2))
    U = controller._hold_controls(X, u_hold)
    t_max = controller.default_t_max() if t_max is None else t_max
    n_hold = math.ceil(controller.latency / dt - 1e-9)
    n_max = max(n_hold, math.ceil(t_max / dt - 1e-9))
    slow = controller._rollout_steps(X, U, n_hold, n_max, dt, {})
    return fast, slow


CASES = [
    ("point_mass", {}, 0.0),
    ("point_mass", {"accel_norm": "box", "max_accel": 3.0}, 0.05),
    ("quadrotor", {}, 0.0),
    ("quadrotor", {"max_rate": 6.0}, 0.04),
    ("diff_drive", {}, 0.0),
    ("diff_drive", {}, 0.1),
]


@pytest.mark.parametrize(("name", "limits", "latency"), CASES)
@pytest.mark.parametrize("n", [1, 37])
def test_compiled_rollouts_match_the_numpy_loop(name, limits, latency, n):
    rng = np.random.default_rng(7 + n)
    model = make_model(name, **limits)
    gains = QuadrotorBrakingGains(attitude_gain=9.0) if latency else None
    controller = BrakingController(model, latency=latency, gains=gains)
    assert model.braking_kernel(controller.deceleration, controller.gains) is not None
    pos = rng.uniform(-3, 3, (n, 3))
    X0 = model.sample_states(pos, lambda top: rng.uniform(0, top, n), rng)
    for u_hold in (None, model.sample_controls(n, rng)):
        fast, slow = _both(controller, X0, 0.01, u_hold=u_hold)
        assert fast.shape == slow.shape
        np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12)


def test_compiled_rollouts_stop_at_the_horizon_and_at_rest():
    model = make_model("quadrotor")
    controller = BrakingController(model)
    rng = np.random.default_rng(3)
    X0 = model.sample_states(np.zeros((5, 3)), lambda top: np.full(5, top), rng)
    fast, slow = _both(controller, X0, 0.02, t_max=0.3)
    assert fast.shape == slow.shape == (5, 16, 10)
    np.testing.assert_allclose(fast, slow, rtol=0, atol=1e-12)
    rest = np.tile(model.rest_state((1.0, 2.0, 3.0)), (3, 1))
    fast, slow = _both(controller, rest, 0.01)
    assert fast.shape == slow.shape == (3, 1, 10)


def test_a_subclass_gets_the_generic_loop():
    from secure3d.dynamics.point_mass import PointMass

    class Slower(PointMass):
        pass

    model = Slower()
    assert model.braking_kernel(4.0, None) is None
    t, X = BrakingController(model).rollout(model.initial_state((0, 0, 1), (1, 0, 0)))
    assert np.linalg.norm(X[-1, 3:6]) < 1e-3
