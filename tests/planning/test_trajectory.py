"""planning/trajectory.py: reading a plan between its nodes."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.dynamics import PointMass
from secure3d.errors import PlanningError
from secure3d.planning.trajectory import Interpolant, interpolate


def _straight(model: PointMass) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constant acceleration along x from rest: positions t^2 / 2, speeds t."""
    t = np.linspace(0.0, 2.0, 5)
    X = np.zeros((5, model.nx))
    X[:, 0], X[:, 3] = 0.5 * t**2, t
    U = np.zeros((5, model.nu))
    U[:, 0] = 1.0
    return t, X, U


def test_the_nodes_are_read_back_exactly_and_constant_acceleration_between_them():
    model = PointMass()
    t, X, U = _straight(model)
    x, u = interpolate(model, t, X, U, t)
    np.testing.assert_allclose(x, X, atol=1e-12, err_msg="at the nodes")
    np.testing.assert_allclose(u, U, atol=1e-12)
    q = np.array([0.25, 1.3, 1.9])
    x, _ = Interpolant(model, t, X, U)(q)
    np.testing.assert_allclose(x[:, 0], 0.5 * q**2, atol=1e-12, err_msg="between the nodes")


def test_times_outside_the_plan_read_its_first_and_last_node():
    model = PointMass()
    t, X, U = _straight(model)
    x, _ = interpolate(model, t, X, U, np.array([-1.0, 5.0]))
    np.testing.assert_allclose(x, X[[0, -1]], atol=1e-12)


def test_node_times_must_increase():
    model = PointMass()
    t, X, U = _straight(model)
    with pytest.raises(PlanningError, match="node times must be increasing"):
        interpolate(model, t[::-1], X, U, t)


def test_interpolant_at_one_time_is_row_zero_read_only_and_kept(rng):
    """``at(t)`` is ``self([t])``'s row, read-only (the tracker and the guard share it), and the
    same arrays again for the same t."""
    from secure3d.dynamics import make_model

    model = make_model("quadrotor")
    t = np.cumsum(rng.uniform(0.05, 0.2, 12)) - 0.05
    X = np.tile(model.initial_state((0.0, 0.0, 1.0)), (12, 1)) + rng.normal(size=(12, 10)) * 0.01
    U = np.tile(model.nominal_control(X[0]), (12, 1))
    ref = Interpolant(model, t, X, U)
    for q in rng.uniform(t[0] - 0.1, t[-1] + 0.1, 20):
        x, u = ref.at(q)
        x0, u0 = ref(np.array([q]))
        np.testing.assert_array_equal(x, x0[0])
        np.testing.assert_array_equal(u, u0[0])
        assert not x.flags.writeable and not u.flags.writeable
        assert ref.at(q)[0] is x
    for bad in (np.nan, np.inf, "1.0", None):
        with pytest.raises(PlanningError, match="Interpolant.at: t must be a finite number"):
            ref.at(bad)
