"""Braking manoeuvres of every vehicle model as compiled loops (issue 18).

:meth:`secure3d.reactive.controller_base.ReactiveController.rollout_batch` advanced a batch of
manoeuvres one RK4 step at a time in numpy: for the one-state manoeuvres of the tracking guard that
is a few hundred small-array calls per step (the quadrotor law alone: a rotation matrix, a cross
product, norms, einsums) and dominated the closed loop's non-planning time. These kernels run the
same loop (hold the control for the latency, then the law until every manoeuvre is at rest or the
horizon ends; RK4 with the control held; the quadrotor's quaternion renormalised after each step)
over the whole batch in one call, with the same arithmetic written out per state, so the states
agree with the numpy loop to rounding (``tests/reactive/test_braking_kernels.py``).

Each kernel returns ``(T, N, nx)`` states, ``T - 1`` the steps taken.
"""

from __future__ import annotations

import math

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)

#: Models whose braking manoeuvres have a kernel here, by ``VehicleModel.name``.
KINDS = {"point_mass": 0, "quadrotor": 1, "diff_drive": 2}


@numba.njit(cache=True, inline="always")
def _f_point_mass(x, u, out):  # pragma: no cover - compiled
    out[0], out[1], out[2] = x[3], x[4], x[5]
    out[3], out[4], out[5], out[6] = u[0], u[1], u[2], u[3]


@numba.njit(cache=True, inline="always")
def _f_quadrotor(x, u, g, out):  # pragma: no cover - compiled
    qw, qx, qy, qz = x[6], x[7], x[8], x[9]
    thrust, wx, wy, wz = u[0], u[1], u[2], u[3]
    zx = 2 * (qx * qz + qw * qy)
    zy = 2 * (qy * qz - qw * qx)
    zz = 1 - 2 * (qx * qx + qy * qy)
    out[0], out[1], out[2] = x[3], x[4], x[5]
    out[3], out[4], out[5] = thrust * zx, thrust * zy, thrust * zz - g
    out[6] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    out[7] = 0.5 * (qw * wx + qy * wz - qz * wy)
    out[8] = 0.5 * (qw * wy - qx * wz + qz * wx)
    out[9] = 0.5 * (qw * wz + qx * wy - qy * wx)


@numba.njit(cache=True, inline="always")
def _f_diff_drive(x, u, out):  # pragma: no cover - compiled
    th, v = x[2], x[3]
    out[0], out[1], out[2] = v * math.cos(th), v * math.sin(th), x[4]
    out[3], out[4] = u[0], u[1]


@numba.njit(cache=True, inline="always")
def _f(kind, x, u, g, out):  # pragma: no cover - compiled
    if kind == 0:
        _f_point_mass(x, u, out)
    elif kind == 1:
        _f_quadrotor(x, u, g, out)
    else:
        _f_diff_drive(x, u, out)


@numba.njit(cache=True)
def _rk4(kind, x, u, h, g, k1, k2, k3, k4, tmp, out):  # pragma: no cover - compiled
    """``rk4_step`` of :mod:`secure3d.dynamics.integrate`, term for term, into ``out``."""
    nx = x.shape[0]
    _f(kind, x, u, g, k1)
    for i in range(nx):
        tmp[i] = x[i] + 0.5 * h * k1[i]
    _f(kind, tmp, u, g, k2)
    for i in range(nx):
        tmp[i] = x[i] + 0.5 * h * k2[i]
    _f(kind, tmp, u, g, k3)
    for i in range(nx):
        tmp[i] = x[i] + h * k3[i]
    _f(kind, tmp, u, g, k4)
    for i in range(nx):
        out[i] = x[i] + (h / 6.0) * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    if kind == 1:  # Quadrotor.project_state: renormalise the quaternion
        n = math.sqrt(out[6] * out[6] + out[7] * out[7] + out[8] * out[8] + out[9] * out[9])
        for i in range(6, 10):
            out[i] = out[i] / n


@numba.njit(cache=True)
def _law_point_mass(x, dt, decel, rest, u):  # pragma: no cover - compiled
    """``PointMass.braking_controls`` and ``braking_at_rest`` of one state."""
    s = math.sqrt(x[3] * x[3] + x[4] * x[4] + x[5] * x[5])
    scale = min(decel, s / dt) / max(s, 1e-300)
    u[0], u[1], u[2], u[3] = -scale * x[3], -scale * x[4], -scale * x[5], 0.0
    return s < rest


@numba.njit(cache=True, inline="always")
def _sign(a):  # pragma: no cover - compiled
    """np.sign of a float."""
    return 1.0 if a > 0 else (-1.0 if a < 0 else a)


@numba.njit(cache=True)
def _law_diff_drive(x, dt, max_accel, max_ang_accel, rest, u):  # pragma: no cover - compiled
    """``DiffDrive.braking_controls`` and ``braking_at_rest`` of one state."""
    v, w = x[3], x[4]
    u[0] = -_sign(v) * min(max_accel, abs(v) / dt)
    u[1] = -_sign(w) * min(max_ang_accel, abs(w) / dt)
    return abs(v) < rest and abs(w) < rest


@numba.njit(cache=True)
def _law_quadrotor(x, p, rest, u):  # pragma: no cover - compiled
    """``Quadrotor._braking`` (controls) and ``braking_at_rest`` of one state; ``p`` holds
    (gravity, deceleration, velocity time constant, attitude gain, max rate, thrust min, max)."""
    g, decel, tau, gain, max_rate, t_min, t_max = p[0], p[1], p[2], p[3], p[4], p[5], p[6]
    vx, vy, vz = x[3], x[4], x[5]
    s = math.sqrt(vx * vx + vy * vy + vz * vz)
    k = min(decel / max(s, 1e-300), 1.0 / tau)
    tx, ty, tz = -k * vx, -k * vy, -k * vz + g
    nt = math.sqrt(tx * tx + ty * ty + tz * tz)
    dx, dy, dz = tx / nt, ty / nt, tz / nt
    # quat_to_matrix: the quaternion normalised first
    nq = math.sqrt(x[6] * x[6] + x[7] * x[7] + x[8] * x[8] + x[9] * x[9])
    w, qx, qy, qz = x[6] / nq, x[7] / nq, x[8] / nq, x[9] / nq
    r00, r01, r02 = 1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - w * qz), 2 * (qx * qz + w * qy)
    r10, r11, r12 = 2 * (qx * qy + w * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - w * qx)
    r20, r21, r22 = 2 * (qx * qz - w * qy), 2 * (qy * qz + w * qx), 1 - 2 * (qx * qx + qy * qy)
    cx, cy, cz = r12 * dz - r22 * dy, r22 * dx - r02 * dz, r02 * dy - r12 * dx
    sin_e = math.sqrt(cx * cx + cy * cy + cz * cz)
    angle = math.atan2(sin_e, r02 * dx + r12 * dy + r22 * dz)
    ratio = angle / max(sin_e, 1e-300) if sin_e > 1e-12 else 1.0
    c = gain * ratio
    wx, wy, wz = c * cx, c * cy, c * cz
    bx = r00 * wx + r10 * wy + r20 * wz
    by = r01 * wx + r11 * wy + r21 * wz
    rate = math.sqrt(bx * bx + by * by)
    sat = min(1.0, max_rate / max(rate, 1e-300))
    thrust = tx * r02 + ty * r12 + tz * r22
    u[0] = min(max(thrust, t_min), t_max)
    u[1], u[2], u[3] = bx * sat, by * sat, 0.0
    return s < rest and angle < rest


@numba.njit(cache=True)
def braking_rollout(kind, X0, U_hold, n_hold, n_max, dt, params, rest):  # pragma: no cover
    """Manoeuvres from the states X0 (N, nx) (already projected): ``U_hold`` (N, nu) for the first
    ``n_hold`` steps, then the braking law of model ``kind`` (:data:`KINDS`; ``params``: point mass
    (deceleration,), diff drive (max_accel, max_ang_accel), quadrotor as :func:`_law_quadrotor`)
    until all are at rest or ``n_max`` steps. Returns (T, N, nx) states."""
    n, nx = X0.shape
    nu = U_hold.shape[1]
    out = np.empty((n_max + 1, n, nx))
    out[0] = X0
    U = np.empty((n, nu))
    k1, k2, k3, k4, tmp = np.empty(nx), np.empty(nx), np.empty(nx), np.empty(nx), np.empty(nx)
    g = params[0] if kind == 1 else 0.0
    steps = 0
    for k in range(n_max):
        X = out[k]
        if k < n_hold:
            U[:] = U_hold
        else:
            all_rest = True
            for i in range(n):
                if kind == 0:
                    r = _law_point_mass(X[i], dt, params[0], rest, U[i])
                elif kind == 1:
                    r = _law_quadrotor(X[i], params, rest, U[i])
                else:
                    r = _law_diff_drive(X[i], dt, params[0], params[1], rest, U[i])
                all_rest = all_rest and r
            if all_rest:
                break
        for i in range(n):
            _rk4(kind, X[i], U[i], dt, g, k1, k2, k3, k4, tmp, out[k + 1, i])
        steps = k + 1
    return out[: steps + 1]
