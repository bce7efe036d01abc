"""The paper's planar bounded-acceleration differential-drive robot (paper section "Results").

State ``(x, y, theta, v, omega)``, control ``(a, alpha)``: ``xdot = v cos(theta)``,
``ydot = v sin(theta)``, ``thetadot = omega``, ``vdot = a``, ``omegadot = alpha``. The body centre
moves in the horizontal plane at the fixed height ``limits.height``; the camera looks along
``theta`` with the mount's pitch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from secure3d.dynamics import _symbolic as sym
from secure3d.dynamics.base import VehicleModel, normalise_fields, vec3
from secure3d.errors import ConfigError
from secure3d.geometry.transforms import yaw_matrix


@dataclass(frozen=True)
class DiffDriveLimits:
    """Limits of the differential-drive robot.

    Attributes
    ----------
    max_accel : float
        Largest |linear acceleration| (m/s^2).
    max_ang_accel : float
        Largest |angular acceleration| (rad/s^2).
    max_speed : float
        Largest |linear speed| (m/s).
    max_ang_speed : float
        Largest |angular speed| (rad/s).
    height : float
        Fixed height of the body centre above the ground plane z = 0 (m), >= 0.
    """

    max_accel: float = 2.0
    max_ang_accel: float = 6.0
    max_speed: float = 2.0
    max_ang_speed: float = 3.0
    height: float = 0.5

    def __post_init__(self) -> None:
        normalise_fields(self, "DiffDriveLimits", allow_zero=("height",))


class DiffDrive(VehicleModel):
    """Differential drive (see module docstring). ``limits`` is a :class:`DiffDriveLimits`."""

    name = "diff_drive"
    feature_map = "diff_drive/v1"
    tracker_kind = "kanayama"
    state_names = ("x", "y", "theta", "v", "omega")
    control_names = ("a", "alpha")
    limits_type = DiffDriveLimits
    planar = True
    heading_follows_path = True
    limits: DiffDriveLimits

    def _control_bounds(self) -> tuple[list[float], list[float]]:
        a, al = self.limits.max_accel, self.limits.max_ang_accel
        return [-a, -al], [a, al]

    def _state_bounds(self) -> tuple[list[float], list[float]]:
        v, w, inf = self.limits.max_speed, self.limits.max_ang_speed, np.inf
        return [-inf, -inf, -inf, -v, -w], [inf, inf, inf, v, w]

    def _f(self, xs: list[Any], us: list[Any], m: ModuleType) -> list[Any]:
        th, v = xs[2], xs[3]
        return [v * m.cos(th), v * m.sin(th), xs[4], us[0], us[1]]

    def _path(self, xs: list[Any], us: list[Any], m: ModuleType) -> list[Any]:
        return []

    def _position(self, xs: list[Any], m: ModuleType) -> list[Any]:
        return [xs[0], xs[1], self.limits.height + 0.0 * xs[0]]

    def _velocity(self, xs: list[Any], m: ModuleType) -> list[Any]:
        th, v = xs[2], xs[3]
        return [v * m.cos(th), v * m.sin(th), 0.0 * v]

    def guess_rates(self, states: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Turn rate from the headings and accelerations from the speeds, by finite differences
        (clipped to the limits). :meth:`initial_state` leaves the turn rate at 0 and the nominal
        control is 0, so a raw guess contradicts its own speed profile: from such guesses IPOPT
        ended in detours (reversing, T 3.1-4.0 s) on a straight 2.5 m passage whose optimum is
        1.55 s, in 4 of 6 baseline solves; from consistent ones, in none."""
        t = np.asarray(times, dtype=float)
        x = np.array(states, dtype=float)
        lim = self.limits
        x[:, 4] = np.clip(np.gradient(np.unwrap(x[:, 2]), t), -lim.max_ang_speed, lim.max_ang_speed)
        rates = np.stack([np.gradient(x[:, 3], t), np.gradient(x[:, 4], t)], axis=1)
        return x, np.clip(rates, self.u_lo, self.u_hi)

    def body_rotation(self, x: Any) -> Any:
        """World-from-body rotation (heading theta): (3, 3) / (N, 3, 3) float, or CasADi 3x3."""
        return yaw_matrix(x[2] if sym.is_casadi(x) else np.asarray(x, dtype=float)[..., 2])

    def yaw(self, x: np.ndarray) -> np.ndarray:
        """Heading theta (rad): scalar or (N,)."""
        return np.asarray(x, dtype=float)[..., 2]

    def initial_state(
        self, position: Any, velocity: Any = (0.0, 0.0, 0.0), yaw: float = 0.0
    ) -> np.ndarray:
        """State (5,) at ``position`` (its z is ignored) heading ``yaw``, at rest in rotation.

        The signed speed is the component of ``velocity`` along the heading: a wheeled robot cannot
        move sideways or vertically, so the rest of ``velocity`` is dropped.
        """
        p, v = vec3(position, "position"), vec3(velocity, "velocity")
        yaw = float(yaw)
        if not np.isfinite(yaw):
            raise ConfigError(f"DiffDrive.initial_state: yaw must be finite, got {yaw!r}")
        speed = float(v[0] * np.cos(yaw) + v[1] * np.sin(yaw))
        return np.array([p[0], p[1], yaw, speed, 0.0])

    @property
    def yaw_rate_limit(self) -> float:
        return float(self.limits.max_ang_speed)

    def rest_residuals(self, x: Any) -> list[Any]:
        """The turn rate: a wheeled robot at rest does not spin in place."""
        return [x[4]]

    def turn_in_place_control(
        self, u: np.ndarray, x: np.ndarray, yaw_error: float, rate_fraction: float, dt: float
    ) -> np.ndarray:
        """Accelerate the turn rate towards a rate proportional to ``yaw_error`` (saturated)."""
        lim = self.limits
        rate = float(np.clip(3.0 * yaw_error, -1, 1)) * rate_fraction * lim.max_ang_speed
        u[1] = np.clip((rate - float(x[4])) / dt, -lim.max_ang_accel, lim.max_ang_accel)
        return u

    def sample_states(
        self, positions: np.ndarray, speeds: Any, rng: np.random.Generator
    ) -> np.ndarray:
        """Random states in the plane; signed speed and turn rate of either sign."""
        n = len(positions)
        X = np.zeros((n, self.nx))
        X[:, :2] = positions[:, :2]
        X[:, 2] = rng.uniform(-math.pi, math.pi, n)
        v = speeds(self.limits.max_speed) * rng.choice([-1.0, 1.0], n)
        w = speeds(self.limits.max_ang_speed) * rng.choice([-1.0, 1.0], n)
        X[:, 3], X[:, 4] = v, w
        return X

    # -- braking law (secure3d.reactive.controllers.BrakingController) ------------------------------
    has_braking_law = True
    closed_form = "heading_capsule"

    def braking_durations(self, deceleration: float, gains: Any) -> tuple[float, float]:
        """The longer of the speed's and the turn rate's braking times, doubled; settling 0.5 s."""
        lim = self.limits
        t_brake = 2.0 * lim.max_speed / deceleration
        return max(t_brake, 2.0 * lim.max_ang_speed / lim.max_ang_accel), 0.5

    def braking_kernel(
        self, deceleration: float, gains: Any
    ) -> tuple[int, tuple[float, ...]] | None:
        """This law compiled (kind 2, the two acceleration limits); None for a subclass."""
        if type(self) is not DiffDrive:
            return None
        return 2, (float(self.limits.max_accel), float(self.limits.max_ang_accel))

    def braking_controls(
        self, X: np.ndarray, dt: float, deceleration: float, gains: Any
    ) -> np.ndarray:
        """The point mass's law on the signed speed (``max_accel``) and on the turn rate
        (``max_ang_accel``)."""
        v, w = X[:, 3], X[:, 4]
        lim = self.limits
        a = -np.sign(v) * np.minimum(lim.max_accel, np.abs(v) / dt)
        alpha = -np.sign(w) * np.minimum(lim.max_ang_accel, np.abs(w) / dt)
        return np.stack([a, alpha], axis=1)

    def braking_at_rest(
        self, X: np.ndarray, rest: float, deceleration: float, gains: Any
    ) -> np.ndarray:
        return (np.abs(X[:, 3]) < rest) & (np.abs(X[:, 4]) < rest)
