"""The paper's 1D example (section "Problem description", after Definition 1).

A robot on the real line, ``x1dot = x2``, ``x2dot = u``, ``u in [-1, 1]``, with the reactive law::

    pi(x(t), O) =  1   if x2(t) < 0 and O < x1(tau)
                  -1   if x2(t) > 0 and O > x1(tau)
                   0   otherwise

(tau: the take-over time). The paper states that the reactive set is the stopping interval
``S_r(x) = [x1, x1 + x2 |x2| / 2]`` (ordered). Taken literally the law only brakes when the obstacle
lies in the direction of travel; an obstacle behind makes it coast for ever, which contradicts the
paper's own stability assumption. :func:`paper_law` is that literal law; :func:`stop_law` brakes
regardless of the obstacle, the reading under which the claim holds for every obstacle. The two
agree whenever the obstacle is ahead, and :func:`reactive_set` (the union over obstacles of the
swept intervals) equals :func:`stopping_interval` for the stop law.

Both laws cap the braking at ``|x2| / dt`` so the last step lands exactly on rest (no chattering).
"""

from __future__ import annotations

import math

import numpy as np

from secure3d.dynamics.integrate import _check_dt, rk4_step
from secure3d.errors import ConfigError

U_MAX = 1.0
#: Speed treated as rest (m/s): the capped last step lands on 0 up to rounding.
REST_SPEED = 1e-12


def f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Double integrator: x (..., 2) = (position, velocity), u (..., 1) -> xdot (..., 2)."""
    x = np.asarray(x, dtype=float)
    return np.stack([x[..., 1], np.asarray(u, dtype=float)[..., 0]], axis=-1)


def _brake(v: np.ndarray, dt: float) -> np.ndarray:
    return -np.sign(v) * np.minimum(U_MAX, np.abs(v) / dt)


def paper_law(x: np.ndarray, obstacle: np.ndarray, takeover: np.ndarray, dt: float) -> np.ndarray:
    """The paper's piecewise law: brake only towards an obstacle in the direction of travel.

    Parameters
    ----------
    x : (N, 2) states. obstacle : (N,) obstacle positions O. takeover : (N,) positions x1(tau).
    dt : the step the control is held for (caps the braking at |x2| / dt).

    Returns
    -------
    u : (N, 1) float.
    """
    v = x[:, 1]
    ahead = ((v > 0) & (obstacle > takeover)) | ((v < 0) & (obstacle < takeover))
    return np.where(ahead, _brake(v, dt), 0.0)[:, None]


def stop_law(x: np.ndarray, dt: float) -> np.ndarray:
    """Stop as quickly as possible whatever the obstacle: ``u = -sign(x2) min(1, |x2| / dt)``."""
    return _brake(x[:, 1], dt)[:, None]


def rollout(
    x0: np.ndarray,
    obstacle: np.ndarray | None = None,
    law: str = "paper",
    dt: float = 0.01,
    t_max: float = 10.0,
) -> np.ndarray:
    """Simulate the reactive manoeuvres of N initial states with RK4.

    Parameters
    ----------
    x0 : (N, 2) initial states (the take-over states).
    obstacle : (N,) obstacle positions (required for ``law="paper"``).
    law : ``"paper"`` (:func:`paper_law`) or ``"stop"`` (:func:`stop_law`).
    dt : step (s). t_max : horizon (s); runs stop early once every manoeuvre is at rest.

    Returns
    -------
    X : (N, T, 2) float.
    """
    dt = _check_dt(dt)
    x = np.array(x0, dtype=float, ndmin=2)
    if law not in ("paper", "stop"):
        raise ConfigError(f"law: must be 'paper' or 'stop', got {law!r}")
    if law == "paper" and obstacle is None:
        raise ConfigError("rollout: the paper's law needs the obstacle positions")
    takeover = x[:, 0].copy()
    out = [x]
    for _ in range(math.ceil(t_max / dt)):
        if np.all(np.abs(x[:, 1]) <= REST_SPEED):
            break
        if law == "paper":
            u = paper_law(x, np.asarray(obstacle, dtype=float), takeover, dt)
        else:
            u = stop_law(x, dt)
        x = rk4_step(f, x, u, dt)
        out.append(x)
    return np.stack(out, axis=1)


def stopping_interval(x0: np.ndarray) -> np.ndarray:
    """The paper's S_r(x) = [x1, x1 + x2 |x2| / 2], ordered: (N, 2) float (lo, hi)."""
    x0 = np.array(x0, dtype=float, ndmin=2)
    end = x0[:, 0] + x0[:, 1] * np.abs(x0[:, 1]) / (2 * U_MAX)
    return np.stack([np.minimum(x0[:, 0], end), np.maximum(x0[:, 0], end)], axis=1)


def swept_interval(X: np.ndarray) -> np.ndarray:
    """Smallest interval (N, 2) containing each simulated manoeuvre X (N, T, 2)."""
    return np.stack([X[:, :, 0].min(axis=1), X[:, :, 0].max(axis=1)], axis=1)


def reactive_set(
    x0: np.ndarray, obstacles: np.ndarray, law: str = "stop", dt: float = 0.01
) -> np.ndarray:
    """Union over ``obstacles`` of the swept intervals from each state (paper Definition 1).

    Parameters
    ----------
    x0 : (N, 2) states. obstacles : (M,) obstacle positions tried for every state.

    Returns
    -------
    (N, 2) float (lo, hi).
    """
    x0 = np.array(x0, dtype=float, ndmin=2)
    obstacles = np.asarray(obstacles, dtype=float).ravel()
    states = np.repeat(x0, len(obstacles), axis=0)
    obs = np.tile(obstacles, len(x0))
    swept = swept_interval(rollout(states, obs, law, dt)).reshape(len(x0), len(obstacles), 2)
    return np.stack([swept[:, :, 0].min(axis=1), swept[:, :, 1].max(axis=1)], axis=1)
