"""3D point mass with yaw: the simplest aerial-robot model (DESIGN.md section 4, "Reactive set").

State ``(px, py, pz, vx, vy, vz, yaw)``, control ``(ax, ay, az, yaw_rate)``; ``pdot = v``,
``vdot = a``, ``yawdot = yaw_rate``. The acceleration is bounded either in norm (``"ball"``:
``|a| <= max_accel``, a path constraint) or per axis (``"box"``: the control bounds). The camera
looks along the yaw heading with the mount's downward pitch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any, Literal

import numpy as np

from secure3d.dynamics import _symbolic as sym
from secure3d.dynamics.base import (
    VehicleModel,
    normalise_fields,
    sample_unit_vectors,
    state_rows,
    vec3,
)
from secure3d.errors import ConfigError
from secure3d.geometry.transforms import yaw_matrix


@dataclass(frozen=True)
class PointMassLimits:
    """Limits of the point mass.

    Attributes
    ----------
    max_accel : float
        Largest acceleration (m/s^2): the norm bound (``"ball"``) or the per-axis bound (``"box"``).
    accel_norm : {"ball", "box"}
        How ``max_accel`` bounds the acceleration vector.
    max_speed : float
        Largest speed |v| (m/s).
    max_yaw_rate : float
        Largest |yaw rate| (rad/s).
    """

    max_accel: float = 4.0
    accel_norm: Literal["ball", "box"] = "ball"
    max_speed: float = 4.0
    max_yaw_rate: float = 2.0

    def __post_init__(self) -> None:
        normalise_fields(self, "PointMassLimits")
        if self.accel_norm not in ("ball", "box"):
            raise ConfigError(
                f"PointMassLimits.accel_norm: must be 'ball' or 'box', got {self.accel_norm!r}"
            )


class PointMass(VehicleModel):
    """Point mass with yaw (see module docstring). ``limits`` is a :class:`PointMassLimits`."""

    name = "point_mass"
    feature_map = "point_mass/v1"
    tracker_kind = "acceleration_pd"
    double_integrator = True
    state_names = ("px", "py", "pz", "vx", "vy", "vz", "yaw")
    control_names = ("ax", "ay", "az", "yaw_rate")
    limits_type = PointMassLimits
    limits: PointMassLimits

    def _control_bounds(self) -> tuple[list[float], list[float]]:
        a, w = self.limits.max_accel, self.limits.max_yaw_rate
        return [-a, -a, -a, -w], [a, a, a, w]

    def _state_bounds(self) -> tuple[list[float], list[float]]:
        v, inf = self.limits.max_speed, np.inf
        return [-inf, -inf, -inf, -v, -v, -v, -inf], [inf, inf, inf, v, v, v, inf]

    def _f(self, xs: list[Any], us: list[Any], m: ModuleType) -> list[Any]:
        return [xs[3], xs[4], xs[5], us[0], us[1], us[2], us[3]]

    def _path(self, xs: list[Any], us: list[Any], m: ModuleType) -> list[Any]:
        lim = self.limits
        g = [xs[3] ** 2 + xs[4] ** 2 + xs[5] ** 2 - lim.max_speed**2]
        if lim.accel_norm == "ball":
            g.append(us[0] ** 2 + us[1] ** 2 + us[2] ** 2 - lim.max_accel**2)
        return g

    def _position(self, xs: list[Any], m: ModuleType) -> list[Any]:
        return xs[0:3]

    def _velocity(self, xs: list[Any], m: ModuleType) -> list[Any]:
        return xs[3:6]

    def body_rotation(self, x: Any) -> Any:
        """World-from-body rotation (yaw only): (3, 3) / (N, 3, 3) float, or CasADi 3x3."""
        return yaw_matrix(x[6] if sym.is_casadi(x) else np.asarray(x, dtype=float)[..., 6])

    def yaw(self, x: np.ndarray) -> np.ndarray:
        """Yaw (rad): scalar or (N,)."""
        return np.asarray(x, dtype=float)[..., 6]

    def initial_state(
        self, position: Any, velocity: Any = (0.0, 0.0, 0.0), yaw: float = 0.0
    ) -> np.ndarray:
        """State (7,) at ``position`` (m) with ``velocity`` (m/s) and ``yaw`` (rad)."""
        p, v = vec3(position, "position"), vec3(velocity, "velocity")
        return np.concatenate([p, v, [float(yaw)]])

    def initial_states(
        self, positions: np.ndarray, velocities: np.ndarray, yaws: np.ndarray
    ) -> np.ndarray:
        """:meth:`initial_state` of N rows at once (the same values): (N, 3), (N, 3), (N,) ->
        (N, 7)."""
        p, v, y = state_rows(positions, velocities, yaws)
        return np.concatenate([p, v, y[:, None]], axis=1)

    def sample_states(
        self, positions: np.ndarray, speeds: Any, rng: np.random.Generator
    ) -> np.ndarray:
        X = self._sample_moving(positions, speeds, rng)
        n = len(X)
        X[:, 6] = rng.uniform(-math.pi, math.pi, n)
        return X

    def sample_controls(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Uniform in the control box; with a norm bound, the acceleration uniform in the ball."""
        U = super().sample_controls(n, rng)
        if self.limits.accel_norm == "ball":
            a = self.limits.max_accel * rng.random(n) ** (1 / 3)
            U[:, :3] = a[:, None] * sample_unit_vectors(n, rng)
        return U

    @property
    def braking_deceleration(self) -> float:
        """Deceleration allowed along any direction (m/s^2): ``max_accel`` for both norms."""
        return self.limits.max_accel

    # -- braking law (secure3d.reactive.controllers.BrakingController) ------------------------------
    has_braking_law = True
    closed_form = "capsule"

    def braking_capsule(
        self, latency: float, deceleration: float, gains: Any
    ) -> tuple[float, float, float, float, float]:
        """Coast for the latency while any held acceleration (the norm bound, or the box's
        diagonal) pushes off the reference, then brake at ``max_accel``."""
        a_hold = self.limits.max_accel * (1.0 if self.limits.accel_norm == "ball" else math.sqrt(3))
        return self.braking_deceleration, latency, a_hold, latency, 0.0

    def braking_kernel(
        self, deceleration: float, gains: Any
    ) -> tuple[int, tuple[float, ...]] | None:
        """This law compiled (kind 0, the deceleration); None for a subclass."""
        return (0, (float(deceleration),)) if type(self) is PointMass else None

    def braking_controls(
        self, X: np.ndarray, dt: float, deceleration: float, gains: Any
    ) -> np.ndarray:
        """``a = -min(a_b, s / dt) v_hat``: the last step lands exactly on v = 0."""
        v = X[:, 3:6]
        s = np.linalg.norm(v, axis=1)
        scale = np.minimum(deceleration, s / dt) / np.maximum(s, 1e-300)
        return np.concatenate([-scale[:, None] * v, np.zeros((len(X), 1))], axis=1)

    def braking_at_rest(
        self, X: np.ndarray, rest: float, deceleration: float, gains: Any
    ) -> np.ndarray:
        return np.linalg.norm(X[:, 3:6], axis=1) < rest
