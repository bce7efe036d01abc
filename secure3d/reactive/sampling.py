"""Random states, held controls and obstacles for fitting and checking reactive sets.

The samplers cover the whole state range the planner may use: speeds up to ``max_speed`` in
uniformly random directions (with extra mass at exactly 0 and exactly ``max_speed``, where the
extremes of the family live), random headings, quadrotor attitudes up to ``max_tilt``, diff-drive
angular speeds up to ``max_ang_speed``. Positions are random too, so that a family that forgot to
add the position would fail.
"""

from __future__ import annotations

import math

import numpy as np

from secure3d.dynamics.base import VehicleModel
from secure3d.dynamics.diff_drive import DiffDrive
from secure3d.dynamics.point_mass import PointMass
from secure3d.dynamics.quadrotor import Quadrotor
from secure3d.errors import ConfigError
from secure3d.geometry.transforms import quat_multiply

#: Fraction of samples placed exactly at rest and exactly at the speed limit.
EXTREME_FRACTION = 0.05
#: Positions are drawn in this cube (m).
POSITION_SPAN = 20.0


def _unit_vectors(n: int, rng: np.random.Generator) -> np.ndarray:
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _speeds(n: int, top: float, rng: np.random.Generator) -> np.ndarray:
    s = top * rng.random(n)
    k = int(EXTREME_FRACTION * n)
    s[:k] = 0.0
    s[k : 2 * k] = top
    return rng.permutation(s)


def sample_states(model: VehicleModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` random states of ``model`` within its limits.

    Parameters
    ----------
    model : the vehicle.
    n : number of states.
    rng : seeded generator.

    Returns
    -------
    X : (n, nx) float.
    """
    if n < 1:
        raise ConfigError(f"n_samples: must be >= 1, got {n!r}")
    lim = model.limits
    X = np.zeros((n, model.nx))
    pos = POSITION_SPAN * (rng.random((n, 3)) - 0.5)
    if isinstance(model, DiffDrive):
        X[:, :2] = pos[:, :2]
        X[:, 2] = rng.uniform(-math.pi, math.pi, n)
        v = _speeds(n, lim.max_speed, rng) * rng.choice([-1.0, 1.0], n)
        w = _speeds(n, lim.max_ang_speed, rng) * rng.choice([-1.0, 1.0], n)
        X[:, 3], X[:, 4] = v, w
        return X
    X[:, :3] = pos
    X[:, 3:6] = _speeds(n, lim.max_speed, rng)[:, None] * _unit_vectors(n, rng)
    if isinstance(model, PointMass):
        X[:, 6] = rng.uniform(-math.pi, math.pi, n)
        return X
    if isinstance(model, Quadrotor):
        yaw = rng.uniform(-math.pi, math.pi, n)
        tilt = _speeds(n, lim.max_tilt, rng)
        axis_angle = rng.uniform(-math.pi, math.pi, n)
        # Tilt about a random horizontal axis, then yaw: q = q_tilt * q_yaw.
        ca, sa = np.cos(tilt / 2), np.sin(tilt / 2)
        ax, ay = np.cos(axis_angle), np.sin(axis_angle)
        cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
        q_t = np.stack([ca, sa * ax, sa * ay, np.zeros(n)], axis=1)
        q_y = np.stack([cy, np.zeros(n), np.zeros(n), sy], axis=1)
        X[:, 6:10] = quat_multiply(q_t, q_y)
        return X
    raise ConfigError(f"sample_states: no sampler for model {model.name!r}")


def sample_hold_controls(model: VehicleModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` random controls within the model's limits, held during the reaction latency.

    Point mass with a norm bound: uniform in the ball. Others: uniform in the control box.

    Returns
    -------
    U : (n, nu) float.
    """
    U = model.u_lo + (model.u_hi - model.u_lo) * rng.random((n, model.nu))
    if isinstance(model, PointMass) and model.limits.accel_norm == "ball":
        a = model.limits.max_accel * rng.random(n) ** (1 / 3)
        U[:, :3] = a[:, None] * _unit_vectors(n, rng)
    return U


def sample_obstacles(
    model: VehicleModel, X: np.ndarray, rng: np.random.Generator, max_distance: float = 5.0
) -> tuple[np.ndarray, np.ndarray]:
    """One random obstacle per state: half points, half boxes, at 0.3..``max_distance`` m clearance.

    Half of them lie within 60 degrees of the direction of travel (the obstacle the camera just
    saw), the rest in uniformly random directions.

    Returns
    -------
    lo, hi : (n, 3) float box corners (``lo == hi`` for point obstacles).
    """
    n = len(X)
    p = model.position(X)
    v = model.velocity(X)
    s = np.linalg.norm(v, axis=1, keepdims=True)
    ahead = np.where(s > 1e-9, v / np.maximum(s, 1e-300), _unit_vectors(n, rng))
    direction = _unit_vectors(n, rng)
    cone = ahead + 0.9 * _unit_vectors(n, rng)
    cone /= np.linalg.norm(cone, axis=1, keepdims=True)
    front = rng.random(n) < 0.5
    direction[front] = cone[front]
    half = rng.uniform(0.05, 1.0, (n, 3)) * (rng.random((n, 1)) < 0.5)
    gap = rng.uniform(0.3, max_distance, n) + model.body_radius
    centre = p + (gap + np.linalg.norm(half, axis=1))[:, None] * direction
    return centre - half, centre + half
