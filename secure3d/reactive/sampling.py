"""Random states, held controls and obstacles for fitting and checking reactive sets.

The samplers cover the whole state range the planner may use: speeds up to ``max_speed`` in
uniformly random directions (with extra mass at exactly 0 and exactly ``max_speed``, where the
extremes of the family live), random headings, quadrotor attitudes up to ``max_tilt``, diff-drive
angular speeds up to ``max_ang_speed``. Positions are random too, so that a family that forgot to
add the position would fail.
"""

from __future__ import annotations

import numpy as np

from secure3d.dynamics.base import VehicleModel, sample_unit_vectors
from secure3d.errors import ConfigError

#: Fraction of samples placed exactly at rest and exactly at the speed limit.
EXTREME_FRACTION = 0.05
#: Positions are drawn in this cube (m).
POSITION_SPAN = 20.0


_unit_vectors = sample_unit_vectors


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
    pos = POSITION_SPAN * (rng.random((n, 3)) - 0.5)
    return model.sample_states(pos, lambda top: _speeds(n, top, rng), rng)


def sample_hold_controls(model: VehicleModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` random controls within the model's limits, held during the reaction latency.

    Point mass with a norm bound: uniform in the ball. Others: uniform in the control box.

    Returns
    -------
    U : (n, nu) float.
    """
    return model.sample_controls(n, rng)


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
