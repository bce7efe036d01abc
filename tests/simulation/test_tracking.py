"""Plan interpolation and feedback trackers: each model follows a feasible reference closely."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.dynamics import MODELS, PointMass, make_model
from secure3d.dynamics.integrate import rollout
from secure3d.errors import ConfigError, GeometryError
from secure3d.simulation.tracking import (
    TRACKERS,
    Reference,
    TrackerGains,
    make_tracker,
    reference_at,
    track,
)

FINE_DT = 1e-3


def feasible_plan(model, x0, controls_of_t, duration, nodes=40):
    """Integrate known controls finely; return plan nodes and the dense truth.

    Returns (node times, node states, node controls, dense times, dense states).
    """
    n = int(round(duration / FINE_DT))
    t = FINE_DT * np.arange(n + 1)
    U = controls_of_t(t)
    X = rollout(model.f, x0, U[:-1], FINE_DT, project=model.project_state)
    idx = np.round(np.linspace(0, n, nodes)).astype(int)
    return t[idx], X[idx], U[idx], t, X


def pm_controls(t):
    return np.column_stack([1.5 * np.cos(t), np.sin(1.3 * t), 0.3 * np.cos(2 * t), 0.5 * np.cos(t)])


def quad_controls(t):
    # Small oscillating roll and pitch with the thrust that holds altitude: speed stays < 3.5 m/s.
    roll, pitch = 0.2 * np.sin(1.5 * t), 0.15 * np.sin(1.1 * t)
    return np.column_stack(
        [
            9.81 / (np.cos(roll) * np.cos(pitch)),
            0.3 * np.cos(1.5 * t),
            0.165 * np.cos(1.1 * t),
            np.full_like(t, 0.2),
        ]
    )


def dd_controls(t):
    return np.column_stack([0.6 * np.cos(0.8 * t), 1.5 * np.sin(1.2 * t)])


def test_hermite_reference_is_exact_for_a_point_mass_under_linear_controls(rng):
    model = make_model("point_mass")
    a0, a1 = rng.normal(size=4), rng.normal(size=4)  # u(t) = a0 + a1 t
    x0 = rng.normal(size=7)
    times = np.sort(rng.uniform(0, 3, 6))
    times[0] = 0.0

    def exact(t):
        t = np.asarray(t)[:, None]
        p = x0[:3] + x0[3:6] * t + a0[:3] * t**2 / 2 + a1[:3] * t**3 / 6
        v = x0[3:6] + a0[:3] * t + a1[:3] * t**2 / 2
        yaw = x0[6] + a0[3] * t + a1[3] * t**2 / 2
        return np.hstack([p, v, yaw])

    states, controls = exact(times), a0 + a1 * times[:, None]
    tq = rng.uniform(0, times[-1], 50)
    x, u = reference_at(times, states, controls, tq, model)
    np.testing.assert_allclose(x, exact(tq), atol=1e-10, err_msg="cubic Hermite on a cubic")
    np.testing.assert_allclose(u, a0 + a1 * tq[:, None], atol=1e-12)
    # Without a model: linear interpolation, exact at the nodes only; clamped outside.
    x_lin, _ = reference_at(times, states, controls, times)
    np.testing.assert_allclose(x_lin, states, atol=1e-12)
    x_before, u_before = Reference(times, states, controls)(-1.0)
    np.testing.assert_array_equal(x_before, states[0])
    np.testing.assert_array_equal(u_before, controls[0])


def test_quadrotor_reference_follows_the_dense_truth_and_ignores_quaternion_signs():
    model = make_model("quadrotor")
    tk, Xk, Uk, t, X = feasible_plan(model, model.initial_state([0, 0, 2]), quad_controls, 4.0)
    ref = Reference(tk, Xk, Uk, model)
    x, _ = ref(t[::7])
    np.testing.assert_allclose(x[:, :6], X[::7, :6], atol=2e-3, err_msg="Hermite vs integration")
    np.testing.assert_allclose(np.linalg.norm(x[:, 6:10], axis=1), 1.0, atol=1e-12)
    flipped = Xk.copy()
    flipped[1::2, 6:10] *= -1
    x_flip, _ = Reference(tk, flipped, Uk, model)(t[::7])
    np.testing.assert_allclose(
        model.body_rotation(x_flip), model.body_rotation(x), atol=1e-9, err_msg="q and -q"
    )


CASES = {
    "point_mass": (pm_controls, [0, 0, 1], (0, 0, 0), 6.0, [0.15, -0.1, 0.05, 0, 0, 0, 0.3]),
    "quadrotor": (quad_controls, [0, 0, 2], (0, 0, 0), 5.0, [0.15, -0.1, 0.05] + [0] * 7),
    "diff_drive": (dd_controls, [0, 0, 0], (0.5, 0, 0), 6.0, [0.08, -0.1, 0.15, 0, 0]),
}


@pytest.mark.parametrize("name", list(CASES))
def test_tracker_follows_a_feasible_reference_from_a_perturbed_start(name):
    controls_of_t, p0, v0, duration, offset = CASES[name]
    model = make_model(name)
    tk, Xk, Uk, t, X = feasible_plan(model, model.initial_state(p0, v0), controls_of_t, duration)
    assert np.linalg.norm(model.velocity(X), axis=1).max() < model.limits.max_speed
    x0 = model.project_state(Xk[0] + np.array(offset, dtype=float))
    ts, Xs, Us = track(make_tracker(model), Reference(tk, Xk, Uk, model), x0, dt=0.01)
    truth = X[np.round(ts / FINE_DT).astype(int)]
    err = np.linalg.norm(model.position(Xs) - model.position(truth), axis=1)
    assert err[0] > 0.1
    assert err[-1] < 0.02, f"{name}: final position error {err[-1]:.4f} m"
    assert err[ts >= 2.0].max() < 0.03, f"{name}: error after 2 s {err[ts >= 2.0].max():.4f} m"
    assert np.all(Us >= model.u_lo - 1e-12) and np.all(Us <= model.u_hi + 1e-12)


@pytest.mark.parametrize("name", ["point_mass", "quadrotor", "diff_drive"])
def test_controls_respect_limits_for_large_errors(name, rng):
    model = make_model(name)
    tracker = make_tracker(model)
    for _ in range(50):
        x = model.project_state(rng.normal(size=model.nx) * 3)
        x_ref = model.project_state(rng.normal(size=model.nx) * 3)
        u_ref = rng.uniform(model.u_lo, model.u_hi)
        u = tracker.control(x, x_ref, u_ref)
        assert np.all(u >= model.u_lo) and np.all(u <= model.u_hi)
        if name == "point_mass":
            assert np.linalg.norm(u[:3]) <= model.limits.max_accel + 1e-9


def test_speed_and_tilt_limits():
    pm = make_model("point_mass", max_speed=2.0)
    x = pm.initial_state([0, 0, 0], [2.0, 0, 0])
    x_ref = pm.initial_state([5, 0, 0], [2.0, 0, 0])
    u = make_tracker(pm).control(x, x_ref, np.zeros(4))
    assert u[0] <= 1e-12, "no acceleration beyond the speed limit"
    quad = make_model("quadrotor", max_tilt=np.radians(20), max_speed=3.0)
    x = quad.initial_state([0, 0, 0])
    far = quad.initial_state([50, 0, 0])
    tracker = make_tracker(quad)
    tilt, speed = [], []
    for _ in range(400):
        x = quad.step(x, tracker.control(x, far, quad.nominal_control(far)), 0.01)
        tilt.append(np.degrees(np.arccos(quad.thrust_axis(x)[2])))
        speed.append(np.linalg.norm(x[3:6]))
    assert 19.0 < max(tilt) < 20.5, "the tilt limit is reached, not exceeded"
    assert 2.9 < max(speed) < 3.0 * 1.02, "the speed limit is reached, barely exceeded"


def test_bad_input_is_rejected():
    pm = make_model("point_mass")
    with pytest.raises(ConfigError, match="kp"):
        TrackerGains(kp=-1.0)
    with pytest.raises(ConfigError, match="point_mass"):
        make_tracker(make_model("quadrotor")).__class__(pm)
    with pytest.raises(GeometryError, match="x_ref"):
        make_tracker(pm).control(np.zeros(7), np.zeros(6), np.zeros(4))
    with pytest.raises(GeometryError, match="increasing"):
        Reference([0.0, 0.0], np.zeros((2, 7)), np.zeros((2, 4)))
    with pytest.raises(GeometryError, match="point_mass"):
        Reference([0.0, 1.0], np.zeros((2, 5)), np.zeros((2, 2)), pm)


def test_a_vehicle_gets_the_tracker_its_model_names_not_one_chosen_by_its_name():
    class Glider(PointMass):
        """A new vehicle: one class naming an existing feedback law."""

        name = "glider"

    tracker = make_tracker(Glider())
    assert isinstance(tracker, TRACKERS[PointMass.tracker_kind])
    assert tracker.model.name == "glider"
    for model in MODELS.values():
        assert make_tracker(model()).kind == model.tracker_kind


def dd_reversing_controls(t):
    # forward at 0.5 m/s, braking through a cusp at t = 2 s, then reversing while turning
    return np.column_stack([np.full_like(t, -0.25), 0.8 * np.sin(0.9 * t)])


def test_diff_drive_tracker_follows_a_plan_that_reverses():
    """Kanayama's law alone pushes a reversing robot away from its plan; mirrored, it follows."""
    model = make_model("diff_drive")
    x0 = model.initial_state([0, 0, 0], (0.5, 0, 0))
    tk, Xk, Uk, t, X = feasible_plan(model, x0, dd_reversing_controls, 5.0, nodes=60)
    speed = X[:, 3]
    assert speed[0] > 0.4 and speed[-1] < -0.7, "the reference must reverse"
    start = model.project_state(Xk[0] + np.array([0.05, -0.08, 0.1, 0, 0]))
    ts, Xs, Us = track(make_tracker(model), Reference(tk, Xk, Uk, model), start, dt=0.01)
    truth = X[np.round(ts / FINE_DT).astype(int)]
    err = np.linalg.norm(model.position(Xs) - model.position(truth), axis=1)
    heading = np.abs(np.angle(np.exp(1j * (Xs[:, 2] - truth[:, 2]))))
    reversing = ts >= 3.0
    assert err[reversing].max() < 0.05, (
        f"position error while reversing {err[reversing].max():.3f} m"
    )
    assert heading[reversing].max() < 0.1, (
        f"heading error while reversing {heading[reversing].max():.3f}"
    )


def _held(model, x0, x_ref, u_ref, seconds=4.0, dt=0.01):
    """The state after tracking the constant reference (x_ref, u_ref) from x0 (the closed loop's
    model.step and tracker)."""
    tracker, x = make_tracker(model), np.asarray(x0, dtype=float)
    for _ in range(int(round(seconds / dt))):
        x = np.asarray(model.step(x, tracker.control(x, x_ref, u_ref), dt), dtype=float)
    return x


@pytest.mark.parametrize("name", ["point_mass", "quadrotor", "diff_drive"])
def test_the_hold_after_a_plan_keeps_the_robot_at_rest_where_the_plan_ends(name):
    """Past a plan's end the closed loop tracks :func:`hold_after`: at rest where the plan ends.

    A minimum-time plan ends mid-manoeuvre. Fed forward for ever, its last node's control (what
    the loop did before) pushed a quadrotor 2.1 m off its goal in forest variant 80; the point mass
    drifts the same way. Here the last node holds a strong control and, for the quadrotor, a 0.6 rad
    roll; the robot arrives moving at 1 m/s, 5 cm off along its heading.
    """
    from types import SimpleNamespace

    from secure3d.geometry.transforms import yaw_matrix
    from secure3d.simulation.modes import ARRIVAL_SPEED, hold_after

    model = make_model(name)
    yaw, p_end = 0.3, np.array([2.0, 1.0, 1.5])
    heading = np.asarray(yaw_matrix(yaw), dtype=float)[:, 0]
    x_end = model.initial_state(p_end, (0.0, 0.0, 0.0), yaw)
    if name == "quadrotor":
        x_end[6:10] = [np.cos(0.3) * np.cos(0.15), np.sin(0.3) * np.cos(0.15), 0.0, np.sin(0.15)]
    u_end = 0.5 * (model.u_lo + model.u_hi) + 0.4 * (model.u_hi - model.u_lo)
    x0 = model.initial_state(p_end - 0.05 * heading, 1.0 * heading, yaw)
    x_ref, u_ref = hold_after(model, SimpleNamespace(states=np.array([x_end])))
    np.testing.assert_allclose(model.position(x_ref), model.position(x_end))
    np.testing.assert_allclose(model.velocity(x_ref), 0.0, atol=1e-12)
    np.testing.assert_allclose(u_ref, model.nominal_control(x_ref))
    x, end = _held(model, x0, x_ref, u_ref), model.position(x_end)
    assert np.linalg.norm(model.position(x) - end) < 0.02
    assert np.linalg.norm(model.velocity(x)) < 0.1 * ARRIVAL_SPEED
    if name != "diff_drive":  # the last node as the hold: off by metres (a / kp), still moving
        x_old = _held(model, x0, x_end, u_end)
        assert np.linalg.norm(model.position(x_old) - end) > 0.5


def test_cross3_is_numpys_cross_bit_for_bit(rng):
    """The tracker's written-out cross product of two 3-vectors is np.cross's, value for value."""
    from secure3d.simulation.tracking import _cross3

    A, B = (
        rng.normal(size=(500, 3)) * 10.0 ** rng.integers(-6, 6, (500, 1)),
        rng.normal(size=(500, 3)),
    )
    for a, b in zip(A, B, strict=True):
        np.testing.assert_array_equal(_cross3(a, b), np.cross(a, b))
