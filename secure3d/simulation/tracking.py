"""Feedback trackers that make each vehicle model follow a planned trajectory.

The planner returns node states and controls (paper eq. NLP); the simulator integrates the model
at a fixed step and needs a control at every step. :class:`Reference` interpolates the plan
(cubic Hermite on the states with ``f(x, u)`` as the node derivatives, linear on the controls),
and a tracker turns the tracking error into a control, clipped to the model's limits:

- point mass: PD on position and velocity plus the planned acceleration as feed-forward; P on yaw
  plus the planned yaw rate;
- quadrotor: the same PD gives a desired acceleration, hence a desired thrust vector; the thrust
  is its projection on the current thrust axis, the desired attitude aligns the body z axis with
  it (heading from the plan), and body rates come from a geometric attitude P controller on SO(3)
  (Lee, Leok & McClamroch, 2010) plus the planned rates as feed-forward;
- differential drive: Kanayama's kinematic tracking law gives a commanded (v, omega)
  (Kanayama et al., 1990), and first-order loops with the planned (a, alpha) as feed-forward
  turn it into the accelerations this model takes as controls.

Every tracker respects the box bounds ``u_lo``/``u_hi``, the point mass's acceleration norm
(``accel_norm="ball"``), the quadrotor's tilt limit and the speed limits (no acceleration that
increases a speed already at its limit).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, fields

import numpy as np

from secure3d.dynamics.base import VehicleModel
from secure3d.errors import ConfigError, GeometryError
from secure3d.validation import is_real


@dataclass(frozen=True)
class TrackerGains:
    """Feedback gains; each tracker uses the fields of its model.

    Attributes
    ----------
    kp : float
        Position gain (1/s^2), point mass and quadrotor. With ``kd = 2 sqrt(kp)`` the error
        dynamics are critically damped.
    kd : float
        Velocity gain (1/s), point mass and quadrotor.
    k_yaw : float
        Yaw gain (1/s), point mass.
    k_att : float
        Attitude gain (1/s), quadrotor: body rate per unit attitude error. Must be well above the
        position loop's bandwidth ``sqrt(kp)``.
    kx : float
        Along-track gain (1/s), differential drive (Kanayama's K_x).
    ky : float
        Cross-track gain (1/m^2), differential drive (Kanayama's K_y).
    k_theta : float
        Heading gain (1/m), differential drive (Kanayama's K_theta).
    k_v, k_omega : float
        Gains (1/s) of the speed and turn-rate loops of the differential drive.
    """

    kp: float = 9.0
    kd: float = 6.0
    k_yaw: float = 4.0
    k_att: float = 12.0
    kx: float = 3.0
    ky: float = 9.0
    k_theta: float = 6.0
    k_v: float = 8.0
    k_omega: float = 12.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not is_real(v) or not math.isfinite(v) or v <= 0:
                raise ConfigError(f"TrackerGains.{f.name}: must be finite and > 0, got {v!r}")
            object.__setattr__(self, f.name, float(v))


def _check_vector(v: object, n: int, what: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        raise GeometryError(f"{what}: expected {n} finite numbers, got shape {a.shape}")
    return a


def _wrap(angle: np.ndarray | float) -> np.ndarray | float:
    """Angle in (-pi, pi]."""
    return np.pi - np.mod(np.pi - angle, 2 * np.pi)


def _vee(S: np.ndarray) -> np.ndarray:
    """The vector of a skew-symmetric matrix."""
    return np.array([S[2, 1], S[0, 2], S[1, 0]])


class Reference:
    """A planned trajectory, interpolated at any time.

    Parameters
    ----------
    times : (K,) float
        Node times (s), strictly increasing.
    states : (K, nx) float
    controls : (K, nu) float
    model : VehicleModel, optional
        With a model the states are cubic Hermite interpolated with ``model.f(x_k, u_k)`` as node
        derivatives (exact for cubic motions, e.g. a point mass under linearly varying controls),
        quaternions are made sign-consistent and renormalised (``model.project_state``).
        Without one, states are linear in time.

    Before the first node the first node is returned; after the last, the last.
    """

    def __init__(
        self,
        times: np.ndarray,
        states: np.ndarray,
        controls: np.ndarray,
        model: VehicleModel | None = None,
    ) -> None:
        t = np.asarray(times, dtype=float).reshape(-1)
        X = np.array(states, dtype=float)
        U = np.array(controls, dtype=float)
        if len(t) < 2 or X.ndim != 2 or U.ndim != 2 or len(X) != len(t) or len(U) != len(t):
            raise GeometryError(
                f"reference: need K >= 2 nodes with times (K,), states (K, nx), controls (K, nu);"
                f" got {t.shape}, {X.shape}, {U.shape}"
            )
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(X)) and np.all(np.isfinite(U))):
            raise GeometryError("reference: times, states and controls must be finite")
        if np.any(np.diff(t) <= 0):
            raise GeometryError("reference: times must be strictly increasing")
        if model is not None and (X.shape[1] != model.nx or U.shape[1] != model.nu):
            raise GeometryError(
                f"reference: {model.name} needs states (K, {model.nx}) and controls"
                f" (K, {model.nu}); got {X.shape} and {U.shape}"
            )
        quat = None if model is None else model.quaternion_slice
        if quat is not None:
            # q and -q are the same attitude; interpolating across a sign flip would pass through 0.
            q = X[:, quat]
            flips = np.sign(np.einsum("ij,ij->i", q[1:], q[:-1]))
            flips[flips == 0] = 1.0
            X[1:, quat] *= np.cumprod(flips)[:, None]
        self.times, self.states, self.controls, self.model = t, X, U, model
        self.derivatives = None if model is None else np.asarray(model.f_batch(X, U), dtype=float)

    @property
    def t_start(self) -> float:
        return float(self.times[0])

    @property
    def t_end(self) -> float:
        return float(self.times[-1])

    def __call__(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Reference state and control at time(s) ``t``.

        Returns
        -------
        x_ref : (nx,) float, or (n, nx) for ``t`` of shape (n,)
        u_ref : (nu,) float, or (n, nu)
        """
        tq = np.asarray(t, dtype=float)
        scalar = tq.ndim == 0
        tq = np.clip(tq.reshape(-1), self.times[0], self.times[-1])
        k = np.clip(np.searchsorted(self.times, tq, side="right") - 1, 0, len(self.times) - 2)
        h = self.times[k + 1] - self.times[k]
        s = ((tq - self.times[k]) / h)[:, None]
        x0, x1 = self.states[k], self.states[k + 1]
        if self.derivatives is None:
            x = (1 - s) * x0 + s * x1
        else:
            d0, d1 = self.derivatives[k], self.derivatives[k + 1]
            s2, s3 = s * s, s * s * s
            x = (
                (2 * s3 - 3 * s2 + 1) * x0
                + (s3 - 2 * s2 + s) * h[:, None] * d0
                + (3 * s2 - 2 * s3) * x1
                + (s3 - s2) * h[:, None] * d1
            )
            x = self.model.project_state(x)
        u = (1 - s) * self.controls[k] + s * self.controls[k + 1]
        return (x[0], u[0]) if scalar else (x, u)


def reference_at(
    plan_times: np.ndarray,
    plan_states: np.ndarray,
    plan_controls: np.ndarray,
    t: float | np.ndarray,
    model: VehicleModel | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """One-off interpolation of a plan at ``t`` (see :class:`Reference`, which caches the node
    derivatives: prefer it inside a simulation loop)."""
    return Reference(plan_times, plan_states, plan_controls, model)(t)


class Tracker(ABC):
    """Turns a tracking error into a control for one vehicle model.

    Attributes
    ----------
    model : VehicleModel
    gains : TrackerGains
    kind : the feedback law, a key of :data:`TRACKERS`: the tracker follows the models whose
        ``tracker_kind`` names it.
    """

    kind: str

    def __init__(self, model: VehicleModel, gains: TrackerGains | None = None) -> None:
        if getattr(model, "tracker_kind", None) != self.kind:
            raise ConfigError(
                f"{type(self).__name__}: tracks models of tracker kind {self.kind!r}, got"
                f" {getattr(model, 'name', model)!r}"
            )
        gains = TrackerGains() if gains is None else gains
        if not isinstance(gains, TrackerGains):
            raise ConfigError(f"gains: expected TrackerGains, got {type(gains).__name__}")
        self.model, self.gains = model, gains

    def control(self, x: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray) -> np.ndarray:
        """The control to apply at state ``x`` to follow ``(x_ref, u_ref)``.

        Parameters
        ----------
        x, x_ref : (nx,) float
        u_ref : (nu,) float
            The planned control at the same time (feed-forward).

        Returns
        -------
        u : (nu,) float, within the model's limits.
        """
        m = self.model
        x = _check_vector(x, m.nx, "x")
        x_ref = _check_vector(x_ref, m.nx, "x_ref")
        u_ref = _check_vector(u_ref, m.nu, "u_ref")
        return np.clip(self._control(x, x_ref, u_ref), m.u_lo, m.u_hi)

    @abstractmethod
    def _control(self, x: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray) -> np.ndarray: ...


def _limit_speed(accel: np.ndarray, v: np.ndarray, max_speed: float, gain: float) -> np.ndarray:
    """Cap the acceleration along ``v`` at ``gain (max_speed - |v|)``: the speed approaches its
    limit exponentially instead of overshooting it (and is pulled back if it exceeds it)."""
    s = float(np.linalg.norm(v))
    if s < 1e-9:
        return accel
    direction = v / s
    excess = float(accel @ direction) - gain * (max_speed - s)
    return accel - max(excess, 0.0) * direction


class PointMassTracker(Tracker):
    """PD + feed-forward on the acceleration, P + feed-forward on the yaw rate."""

    kind = "acceleration_pd"

    def _control(self, x: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray) -> np.ndarray:
        g, lim = self.gains, self.model.limits
        a = u_ref[:3] + g.kp * (x_ref[:3] - x[:3]) + g.kd * (x_ref[3:6] - x[3:6])
        a = _limit_speed(a, x[3:6], lim.max_speed, g.kd)
        if lim.accel_norm == "ball":
            n = float(np.linalg.norm(a))
            if n > lim.max_accel:
                a = a * (lim.max_accel / n)
        else:
            a = np.clip(a, -lim.max_accel, lim.max_accel)
        yaw_rate = u_ref[3] + g.k_yaw * _wrap(x_ref[6] - x[6])
        return np.append(a, yaw_rate)


class QuadrotorTracker(Tracker):
    """Desired acceleration (PD + feed-forward) -> thrust and attitude -> body rates (SO(3) P)."""

    kind = "geometric_attitude"

    def _control(self, x: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray) -> np.ndarray:
        g, m = self.gains, self.model
        lim = m.limits
        e3 = np.array([0.0, 0.0, 1.0])
        a_ref = np.asarray(m.f(x_ref, u_ref), dtype=float)[3:6]
        a_des = a_ref + g.kp * (x_ref[:3] - x[:3]) + g.kd * (x_ref[3:6] - x[3:6])
        a_des = _limit_speed(a_des, x[3:6], lim.max_speed, g.kd)
        thrust_vec = a_des + lim.gravity * e3
        thrust_vec = _tilt_limited(thrust_vec, lim.max_tilt)
        R = np.asarray(m.body_rotation(x), dtype=float)
        R_ref = np.asarray(m.body_rotation(x_ref), dtype=float)
        b3 = thrust_vec / np.linalg.norm(thrust_vec)
        # Heading from the plan's body x axis (its y axis if x is along the thrust direction).
        side = _cross3(b3, R_ref[:, 0])
        if np.linalg.norm(side) > 1e-3:
            b2 = side / np.linalg.norm(side)
            b1 = _cross3(b2, b3)
        else:
            b1 = _cross3(R_ref[:, 1], b3)
            b1 /= np.linalg.norm(b1)
            b2 = _cross3(b3, b1)
        R_des = np.column_stack([b1, b2, b3])
        e_R = 0.5 * _vee(R_des.T @ R - R.T @ R_des)
        rates = R.T @ R_des @ u_ref[1:4] - g.k_att * e_R
        thrust = float(thrust_vec @ R[:, 2])
        return np.concatenate([[thrust], rates])


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two (3,) vectors, the same products and differences written out (called a
    few times per simulation step, where np.cross's overhead showed: ~35 us against ~3 us)."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _tilt_limited(thrust_vec: np.ndarray, max_tilt: float) -> np.ndarray:
    """Keep the thrust direction within ``max_tilt`` of world up (shrinking the horizontal part)."""
    vertical = max(float(thrust_vec[2]), 1e-6)
    horizontal = thrust_vec[:2]
    h = float(np.linalg.norm(horizontal))
    h_max = vertical * math.tan(max_tilt) if max_tilt < math.pi / 2 else np.inf
    if h > h_max:
        horizontal = horizontal * (h_max / h)
    return np.array([horizontal[0], horizontal[1], vertical])


class DiffDriveTracker(Tracker):
    """Kanayama's kinematic tracking law with first-order (v, omega) loops (dynamic extension).

    Kanayama's law needs the reference to move forward (``v_r >= 0``): with ``v_r < 0`` its
    heading and lateral corrections change sign and push the robot away from the plan (a reversing
    replan was lost with heading errors of 2.5-3.5 rad). While the reference reverses, the law is
    applied to the *mirrored* robot, the same body with heading ``theta + pi`` and forward speed
    ``-v``, which moves forward along the reference; its speed command is negated back. Both laws
    give the same command at ``v_r = 0``, so the control is continuous at a cusp.
    """

    kind = "kanayama"

    def _control(self, x: np.ndarray, x_ref: np.ndarray, u_ref: np.ndarray) -> np.ndarray:
        g, lim = self.gains, self.model.limits
        px, py, th, v, w = x
        v_r, w_r = x_ref[3], x_ref[4]
        mirror = -1.0 if v_r < 0.0 else 1.0  # reversing: track the mirrored robot forwards
        dx, dy = x_ref[0] - px, x_ref[1] - py
        c, s = mirror * math.cos(th), mirror * math.sin(th)
        e_x, e_y = c * dx + s * dy, -s * dx + c * dy
        e_th = float(_wrap(x_ref[2] - th))
        v_m = mirror * v_r
        v_cmd = mirror * (v_m * math.cos(e_th) + g.kx * e_x)
        w_cmd = w_r + v_m * (g.ky * e_y + g.k_theta * math.sin(e_th))
        v_cmd = float(np.clip(v_cmd, -lim.max_speed, lim.max_speed))
        w_cmd = float(np.clip(w_cmd, -lim.max_ang_speed, lim.max_ang_speed))
        a = u_ref[0] + g.k_v * (v_cmd - v)
        alpha = u_ref[1] + g.k_omega * (w_cmd - w)
        return np.array([a, alpha])


#: Feedback law (a vehicle model's ``tracker_kind``) -> its tracker.
TRACKERS: dict[str, type[Tracker]] = {
    cls.kind: cls for cls in (PointMassTracker, QuadrotorTracker, DiffDriveTracker)
}


def make_tracker(model: VehicleModel, gains: TrackerGains | None = None) -> Tracker:
    """The tracker for ``model`` (the law its ``tracker_kind`` names), with default or given
    gains."""
    try:
        cls = TRACKERS[model.tracker_kind]
    except (KeyError, AttributeError):
        raise ConfigError(f"model: no tracker for {getattr(model, 'name', model)!r}") from None
    return cls(model, gains)


def track(
    tracker: Tracker,
    reference: Reference,
    x0: np.ndarray,
    dt: float,
    t_final: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fly ``reference`` from ``x0`` with ``tracker``: RK4 at fixed step ``dt``, control held.

    Parameters
    ----------
    tracker : Tracker
    reference : Reference
    x0 : (nx,) float
        Initial state (may differ from the plan's first node).
    dt : float
        Integration and control step (s).
    t_final : float, optional
        End time (s); default the reference's last node time.

    Returns
    -------
    times : (T + 1,) float
    states : (T + 1, nx) float
    controls : (T, nu) float
    """
    dt = float(dt)
    if not (math.isfinite(dt) and dt > 0):
        raise ConfigError(f"dt: must be finite and > 0, got {dt!r}")
    t0 = reference.t_start
    t1 = reference.t_end if t_final is None else float(t_final)
    steps = max(int(math.ceil((t1 - t0) / dt - 1e-9)), 0)
    model = tracker.model
    times = t0 + dt * np.arange(steps + 1)
    X = np.empty((steps + 1, model.nx))
    U = np.empty((steps, model.nu))
    X[0] = _check_vector(x0, model.nx, "x0")
    refs_x, refs_u = reference(times[:-1])
    for i in range(steps):
        U[i] = tracker.control(X[i], refs_x[i], refs_u[i])
        X[i + 1] = model.step(X[i], U[i], dt)
    return times, X, U
