"""Quadrotor with mass-normalised collective thrust and body-rate control.

State ``(px, py, pz, vx, vy, vz, qw, qx, qy, qz)``, control ``(thrust, wx, wy, wz)``:
``pdot = v``, ``vdot = R(q) e3 T - g e3``, ``qdot = 0.5 q (x) (0, w)`` (Hamilton product, body
rates). The camera is fixed in the body frame, so tilting to accelerate or brake moves the field of
view with the attitude.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from secure3d.dynamics import _symbolic as sym
from secure3d.dynamics.base import VehicleModel, normalise_fields, state_rows, vec3
from secure3d.errors import ConfigError
from secure3d.geometry.transforms import quat_multiply, quat_to_matrix
from secure3d.validation import is_real


@dataclass(frozen=True)
class QuadrotorBrakingGains:
    """Gains of the quadrotor braking law.

    Attributes
    ----------
    decel_fraction : float
        Fraction of the largest deceleration the thrust range allows in every direction
        (``min(thrust_max - g, g - thrust_min, g sin(max_tilt))``) that the law demands, in (0, 1];
        the rest is margin for the attitude error.
    velocity_time_constant : float
        Below ``decel * tau`` m/s the demanded deceleration is ``v / tau`` (tau in s): a smooth,
        chatter-free approach to rest.
    attitude_gain : float
        Body rate per radian of thrust-axis error (1/s), saturated at ``max_rate``.
    """

    decel_fraction: float = 0.9
    velocity_time_constant: float = 0.25
    attitude_gain: float = 12.0

    def __post_init__(self) -> None:
        for name in ("decel_fraction", "velocity_time_constant", "attitude_gain"):
            v = getattr(self, name)
            if not is_real(v) or not math.isfinite(v) or v <= 0:
                raise ConfigError(
                    f"QuadrotorBrakingGains.{name}: must be finite and > 0, got {v!r}"
                )
        if self.decel_fraction > 1:
            raise ConfigError(
                f"QuadrotorBrakingGains.decel_fraction: must be <= 1, got {self.decel_fraction}"
            )


@dataclass(frozen=True)
class QuadrotorLimits:
    """Limits of the quadrotor (mass-normalised, so thrusts are accelerations).

    Attributes
    ----------
    thrust_min, thrust_max : float
        Collective thrust range (m/s^2). ``thrust_min < gravity < thrust_max`` (else it cannot
        hover).
    max_rate : float
        Largest |roll/pitch body rate| (rad/s).
    max_yaw_rate : float
        Largest |yaw body rate| (rad/s).
    max_speed : float
        Largest speed |v| (m/s).
    gravity : float
        Gravitational acceleration (m/s^2).
    max_tilt : float
        Largest angle between the thrust axis and world up the planner may use (rad, in (0, pi/2]);
        a path constraint, and the attitude range the reactive sets are fitted on.
    """

    thrust_min: float = 1.0
    thrust_max: float = 20.0
    max_rate: float = 4.0
    max_yaw_rate: float = 2.0
    max_speed: float = 5.0
    gravity: float = 9.81
    max_tilt: float = math.radians(60.0)

    def __post_init__(self) -> None:
        normalise_fields(self, "QuadrotorLimits", allow_zero=("thrust_min",))
        if self.thrust_max <= self.gravity:
            raise ConfigError(
                f"QuadrotorLimits.thrust_max: {self.thrust_max} m/s^2 cannot hover against gravity "
                f"{self.gravity} m/s^2 (need thrust_max > gravity)"
            )
        if self.thrust_min >= self.gravity:
            raise ConfigError(
                f"QuadrotorLimits.thrust_min: {self.thrust_min} m/s^2 cannot hover "
                f"(need thrust_min < gravity = {self.gravity} m/s^2)"
            )
        if self.max_tilt > math.pi / 2:
            raise ConfigError(
                f"QuadrotorLimits.max_tilt: must be in (0, pi/2] rad, got {self.max_tilt!r}"
            )


class Quadrotor(VehicleModel):
    """Quadrotor (see module docstring). ``limits`` is a :class:`QuadrotorLimits`."""

    name = "quadrotor"
    feature_map = "quadrotor/v1"
    tracker_kind = "geometric_attitude"
    state_names = ("px", "py", "pz", "vx", "vy", "vz", "qw", "qx", "qy", "qz")
    control_names = ("thrust", "wx", "wy", "wz")
    limits_type = QuadrotorLimits
    quaternion_slice = slice(6, 10)
    limits: QuadrotorLimits

    def _control_bounds(self) -> tuple[list[float], list[float]]:
        lim = self.limits
        return (
            [lim.thrust_min, -lim.max_rate, -lim.max_rate, -lim.max_yaw_rate],
            [lim.thrust_max, lim.max_rate, lim.max_rate, lim.max_yaw_rate],
        )

    def _state_bounds(self) -> tuple[list[float], list[float]]:
        v, inf = self.limits.max_speed, np.inf
        return [-inf, -inf, -inf, -v, -v, -v, -1, -1, -1, -1], [inf, inf, inf, v, v, v, 1, 1, 1, 1]

    def _f(self, xs: list[Any], us: list[Any], m: ModuleType) -> list[Any]:
        qw, qx, qy, qz = xs[6:10]
        thrust, wx, wy, wz = us
        # Thrust axis R(q) e3 (third column of quat_rotation).
        zx, zy, zz = 2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx), 1 - 2 * (qx * qx + qy * qy)
        g = self.limits.gravity
        return [
            xs[3],
            xs[4],
            xs[5],
            thrust * zx,
            thrust * zy,
            thrust * zz - g,
            0.5 * (-qx * wx - qy * wy - qz * wz),
            0.5 * (qw * wx + qy * wz - qz * wy),
            0.5 * (qw * wy - qx * wz + qz * wx),
            0.5 * (qw * wz + qx * wy - qy * wx),
        ]

    def _path(self, xs: list[Any], us: list[Any], m: ModuleType) -> list[Any]:
        lim = self.limits
        qx, qy = xs[7], xs[8]
        return [
            xs[3] ** 2 + xs[4] ** 2 + xs[5] ** 2 - lim.max_speed**2,
            math.cos(lim.max_tilt) - (1 - 2 * (qx * qx + qy * qy)),
        ]

    def _position(self, xs: list[Any], m: ModuleType) -> list[Any]:
        return xs[0:3]

    def _velocity(self, xs: list[Any], m: ModuleType) -> list[Any]:
        return xs[3:6]

    def body_rotation(self, x: Any) -> Any:
        """World-from-body rotation R(q): (3, 3) / (N, 3, 3) float, or CasADi 3x3.

        numpy normalises q first; CasADi uses q as given (the NLP keeps |q| = 1).
        """
        return quat_to_matrix(
            x[6:10] if sym.is_casadi(x) else np.asarray(x, dtype=float)[..., 6:10]
        )

    def yaw(self, x: np.ndarray) -> np.ndarray:
        """Heading of the body x axis about world z (rad): scalar or (N,)."""
        R = self.body_rotation(x)
        return np.arctan2(R[..., 1, 0], R[..., 0, 0])

    def thrust_axis(self, x: np.ndarray) -> np.ndarray:
        """World direction of the thrust, ``R(q) e3``: (3,) or (N, 3)."""
        return self.body_rotation(x)[..., :, 2]

    def project_state(self, x: np.ndarray) -> np.ndarray:
        """Renormalise the quaternion (RK4 drifts off |q| = 1 by O(dt^5) per step)."""
        x = np.array(x, dtype=float)
        q = x[..., 6:10]
        x[..., 6:10] = q / np.linalg.norm(q, axis=-1, keepdims=True)
        return x

    def initial_state(
        self, position: Any, velocity: Any = (0.0, 0.0, 0.0), yaw: float = 0.0
    ) -> np.ndarray:
        """Level state (10,) at ``position`` with ``velocity`` and heading ``yaw`` (rad)."""
        p, v = vec3(position, "position"), vec3(velocity, "velocity")
        h = 0.5 * float(yaw)
        return np.concatenate([p, v, [math.cos(h), 0.0, 0.0, math.sin(h)]])

    def initial_states(
        self, positions: np.ndarray, velocities: np.ndarray, yaws: np.ndarray
    ) -> np.ndarray:
        """:meth:`initial_state` of N rows at once (the same values): (N, 3), (N, 3), (N,) ->
        (N, 10)."""
        p, v, y = state_rows(positions, velocities, yaws)
        h = 0.5 * y
        q = np.zeros((len(h), 4))
        q[:, 0] = [math.cos(a) for a in h.tolist()]  # math's, as initial_state: the same bits
        q[:, 3] = [math.sin(a) for a in h.tolist()]
        return np.concatenate([p, v, q], axis=1)

    def nominal_control(self, x: np.ndarray) -> np.ndarray:
        """Hover thrust ``gravity`` and zero body rates: (4,) or (N, 4)."""
        u = np.zeros((*np.shape(x)[:-1], self.nu))
        u[..., 0] = self.limits.gravity
        return u

    @property
    def nominal_accel(self) -> float:
        """3 m/s^2: thrust and tilt bound the acceleration together, with no single limit; the
        initial guess's time-parametrisation assumes this much."""
        return 3.0

    def sample_states(
        self, positions: np.ndarray, speeds: Any, rng: np.random.Generator
    ) -> np.ndarray:
        """Random states; the attitude tilted about a random horizontal axis, then yawed."""
        X = self._sample_moving(positions, speeds, rng)
        n = len(X)
        yaw = rng.uniform(-math.pi, math.pi, n)
        tilt = speeds(self.limits.max_tilt)
        axis_angle = rng.uniform(-math.pi, math.pi, n)
        # Tilt about a random horizontal axis, then yaw: q = q_tilt * q_yaw.
        ca, sa = np.cos(tilt / 2), np.sin(tilt / 2)
        ax, ay = np.cos(axis_angle), np.sin(axis_angle)
        cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
        q_t = np.stack([ca, sa * ax, sa * ay, np.zeros(n)], axis=1)
        q_y = np.stack([cy, np.zeros(n), np.zeros(n), sy], axis=1)
        X[:, 6:10] = quat_multiply(q_t, q_y)
        return X

    # -- braking law (secure3d.reactive.controllers.BrakingController) ------------------------------
    has_braking_law = True
    closed_form = "capsule"

    def braking_capsule(
        self, latency: float, deceleration: float, gains: QuadrotorBrakingGains
    ) -> tuple[float, float, float, float, float]:
        """Braking at ``deceleration`` after the thrust axis has turned (saturated body rates,
        then one attitude time constant), with the thrust error of that turn."""
        lim = self.limits
        g, a_b = lim.gravity, deceleration
        brake_tilt = math.asin(min(1.0, a_b / g))
        # Largest angle between the thrust axis (tilt <= max_tilt, plus what the held rates add
        # during the latency) and any braking thrust direction (tilt <= brake_tilt).
        turn = min(math.pi, lim.max_tilt + lim.max_rate * latency + brake_tilt)
        # Saturated turn at max_rate, then one attitude time constant to settle.
        t_turn = latency + turn / lim.max_rate + 1.0 / gains.attitude_gain
        # The law's thrust error is |t| sin(angle) <= (g + a_b) sin(angle); a held command during
        # the latency may use up to thrust_max and differs from the braking reference by a_b more.
        if latency > 0:
            err = lim.thrust_max * math.sin(min(turn, math.pi / 2)) + a_b
        else:
            err = (g + a_b) * math.sin(min(turn, math.pi / 2))
        tau = gains.velocity_time_constant
        return a_b, 0.0, err, t_turn, 0.5 * a_b * tau * tau

    braking_uses_gains = True

    def braking_deceleration_with(self, gains: QuadrotorBrakingGains) -> float:
        """``decel_fraction`` of the deceleration the thrust range allows in every direction."""
        lim = self.limits
        g = lim.gravity
        avail = min(lim.thrust_max - g, g - lim.thrust_min, g * math.sin(lim.max_tilt))
        return gains.decel_fraction * avail

    def braking_durations(
        self, deceleration: float, gains: QuadrotorBrakingGains
    ) -> tuple[float, float]:
        """Twice the braking time from the top speed; settling: 12 velocity time constants."""
        return 2.0 * self.limits.max_speed / deceleration, 12.0 * gains.velocity_time_constant

    def braking_kernel(
        self, deceleration: float, gains: QuadrotorBrakingGains
    ) -> tuple[int, tuple[float, ...]] | None:
        """This law compiled (kind 1; gravity, deceleration, gains, rate and thrust limits); None
        for a subclass."""
        if type(self) is not Quadrotor:
            return None
        lim = self.limits
        return 1, (
            lim.gravity,
            float(deceleration),
            gains.velocity_time_constant,
            gains.attitude_gain,
            lim.max_rate,
            lim.thrust_min,
            lim.thrust_max,
        )

    def braking_controls(
        self, X: np.ndarray, dt: float, deceleration: float, gains: QuadrotorBrakingGains
    ) -> np.ndarray:
        return self._braking(X, deceleration, gains)[0]

    def braking_at_rest(
        self, X: np.ndarray, rest: float, deceleration: float, gains: QuadrotorBrakingGains
    ) -> np.ndarray:
        """Slow and with the thrust axis aligned (attitude settled)."""
        stopped = np.linalg.norm(X[:, 3:6], axis=1) < rest
        stopped &= self._braking(X, deceleration, gains)[1] < rest
        return stopped

    def _braking(
        self, X: np.ndarray, deceleration: float, gains: QuadrotorBrakingGains
    ) -> tuple[np.ndarray, np.ndarray]:
        """Controls (N, 4) and the thrust-axis error angle (N,) of the quadrotor law."""
        lim = self.limits
        v = X[:, 3:6]
        s = np.linalg.norm(v, axis=1)
        k = np.minimum(deceleration / np.maximum(s, 1e-300), 1.0 / gains.velocity_time_constant)
        t_des = -k[:, None] * v
        t_des[:, 2] += lim.gravity
        d = t_des / np.linalg.norm(t_des, axis=1, keepdims=True)
        R = self.body_rotation(X)
        z_b = R[:, :, 2]
        cross = np.cross(z_b, d)
        sin_e = np.linalg.norm(cross, axis=1)
        angle = np.arctan2(sin_e, np.einsum("ij,ij->i", z_b, d))
        # angle / sin(angle) -> 1 as the error vanishes; the axis is then irrelevant.
        ratio = np.where(sin_e > 1e-12, angle / np.maximum(sin_e, 1e-300), 1.0)
        w_world = (gains.attitude_gain * ratio)[:, None] * cross
        w_body = np.einsum("nji,nj->ni", R, w_world)
        rate = np.linalg.norm(w_body[:, :2], axis=1)
        w_body *= np.minimum(1.0, lim.max_rate / np.maximum(rate, 1e-300))[:, None]
        w_body[:, 2] = 0.0
        thrust = np.clip(np.einsum("ij,ij->i", t_des, z_b), lim.thrust_min, lim.thrust_max)
        return np.concatenate([thrust[:, None], w_body], axis=1), angle
