"""Fixed-step fourth-order Runge-Kutta integration, shared by every vehicle model.

The control is held constant over a step (zero-order hold), which is how the simulator and the
reactive controllers apply it. ``f`` may be batched: with ``x`` of shape ``(N, nx)`` and ``u`` of
shape ``(N, nu)`` one call advances N states at once.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from secure3d.errors import ConfigError

Dynamics = Callable[[Any, Any], Any]


def _check_dt(dt: float) -> float:
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0:
        raise ConfigError(f"dt: must be finite and > 0, got {dt!r}")
    return dt


def rk4_step(f: Dynamics, x: Any, u: Any, dt: float) -> Any:
    """One classical RK4 step of ``xdot = f(x, u)`` with ``u`` held over the step.

    Parameters
    ----------
    f : dynamics ``f(x, u) -> xdot``; numpy (possibly batched) or CasADi.
    x : (nx,) or (N, nx) float, or CasADi column.
    u : (nu,) or (N, nu) float, or CasADi column.
    dt : step (s), > 0.

    Returns
    -------
    x_next : same shape and type as ``x``. Local error O(dt^5), global error O(dt^4).
    """
    h = float(dt)
    k1 = f(x, u)
    k2 = f(x + 0.5 * h * k1, u)
    k3 = f(x + 0.5 * h * k2, u)
    k4 = f(x + h * k3, u)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def rollout(
    f: Dynamics,
    x0: np.ndarray,
    controls: np.ndarray,
    dt: float,
    project: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Integrate a control sequence with RK4 (zero-order hold).

    Parameters
    ----------
    f : numpy dynamics ``f(x, u)``, batched or not.
    x0 : (nx,) or (N, nx) float initial state(s).
    controls : (T, nu) or (T, N, nu) float, one control per step.
    dt : step (s).
    project : optional map applied after every step (e.g. quaternion renormalisation).

    Returns
    -------
    X : (T + 1, nx) or (T + 1, N, nx) float, ``X[0] = x0``.
    """
    dt = _check_dt(dt)
    x = np.asarray(x0, dtype=float)
    us = np.asarray(controls, dtype=float)
    if us.ndim != x.ndim + 1:
        raise ValueError(f"controls: expected {x.ndim + 1} dimensions, got shape {us.shape}")
    out = np.empty((len(us) + 1, *x.shape))
    out[0] = x
    for k, u in enumerate(us):
        x = rk4_step(f, x, u, dt)
        if project is not None:
            x = project(x)
        out[k + 1] = x
    return out
