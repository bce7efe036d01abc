"""Reactive controllers pi(x, O): what the robot does once an unseen obstacle shows up.

The paper (section "The reactive set", Definition 1) only assumes a stabilising law whose
manoeuvres stay near the take-over point; the reactive set S_r(x) bounds every manoeuvre it can
produce. Two laws are provided:

- :class:`BrakingController`: stop as hard as the limits allow (point mass: full deceleration
  against v; quadrotor: an attitude controller turns the thrust against v, then brakes; diff drive:
  full linear and angular deceleration). It ignores the obstacle, so its reactive set is the
  stopping manoeuvre.
- :class:`MPCReactiveController`: the paper's MPC (section "Results"): penalises drift from the
  take-over point and closeness to the obstacle, within the acceleration bound (point mass).

Every controller returns a control for a state, and rolls out whole manoeuvres, one at a time or
vectorised over N initial states (``rollout_batch``), which is what makes 10,000-manoeuvre
containment checks cheap. During the first ``latency`` seconds the held control ``u_hold`` is
applied (the planner's last command), then the law takes over.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from secure3d.dynamics.base import VehicleModel
from secure3d.dynamics.quadrotor import QuadrotorBrakingGains
from secure3d.errors import ConfigError
from secure3d.reactive.controller_base import REST_SPEED, ReactiveController
from secure3d.reactive.mpc import MPCReactiveController, MPCWeights, obstacle_direction

__all__ = [
    "REST_SPEED",
    "BrakingController",
    "MPCReactiveController",
    "MPCWeights",
    "QuadrotorBrakingGains",
    "ReactiveController",
    "obstacle_direction",
]


# ------------------------------------------------------------------------------------------------
# Braking
# ------------------------------------------------------------------------------------------------


class BrakingController(ReactiveController):
    """Maximum braking for any model (see module docstring); ignores the obstacle.

    Parameters
    ----------
    model : PointMass, Quadrotor or DiffDrive.
    latency : reaction delay (s).
    gains : quadrotor only, :class:`QuadrotorBrakingGains`.

    Notes
    -----
    Point mass: ``a = -min(a_b, s / dt) v_hat`` with ``a_b = max_accel`` (for the box bound too,
    conservatively). Capping at ``s / dt`` makes the last step land exactly on v = 0 (no
    chattering); since every step maps v to the proximal point ``prox_{a_b dt |.|}(v)``, the path is
    the straight stopping segment of length ``s^2 / (2 a_b)`` up to ``a_b dt^2 / 8``.
    Diff drive: the same law on v (with ``max_accel``) and on omega (with ``max_ang_accel``).
    Quadrotor: demanded acceleration ``a_des = -min(a_b, s / tau) v_hat`` with ``a_b`` the
    deceleration available in every direction, thrust vector ``t = a_des + g e3``; body rates turn
    the thrust axis towards ``t`` (``k * angle`` about ``z_b x t_hat``, saturated at ``max_rate``)
    and the collective thrust is ``clip(t . z_b, thrust_min, thrust_max)``.
    """

    name = "braking"

    def __init__(
        self, model: VehicleModel, latency: float = 0.0, gains: QuadrotorBrakingGains | None = None
    ):
        super().__init__(model, latency)
        if not model.has_braking_law:
            raise ConfigError(f"BrakingController.model: unsupported model {model.name!r}")
        self.gains = QuadrotorBrakingGains() if gains is None else gains
        self.deceleration = model.braking_deceleration_with(self.gains)

    def config(self) -> dict[str, Any]:
        """Name, latency and (for a law with gains: the quadrotor's) the gains."""
        out = super().config()
        if self.model.braking_uses_gains:
            out["gains"] = dataclasses.asdict(self.gains)
        return out

    def default_t_max(self) -> float:
        """Latency + twice the braking time from the top speed + settling (s)."""
        t_brake, settle = self.model.braking_durations(self.deceleration, self.gains)
        return self.latency + t_brake + settle

    # -- laws ------------------------------------------------------------------------------------
    def control_batch(self, X: np.ndarray, dt: float = 0.01, **context: Any) -> np.ndarray:
        """Braking controls (N, nu) for states X (N, nx) held for ``dt`` seconds (the vehicle's
        law: :meth:`~secure3d.dynamics.base.VehicleModel.braking_controls`)."""
        return self.model.braking_controls(
            np.asarray(X, dtype=float), dt, self.deceleration, self.gains
        )

    def _compiled_rollout(
        self,
        X: np.ndarray,
        U_hold: np.ndarray,
        n_hold: int,
        n_max: int,
        dt: float,
        context: dict[str, Any],
    ) -> np.ndarray | None:
        """The vehicle's braking manoeuvres in one compiled loop
        (:mod:`secure3d.dynamics._braking_kernels`), the same states as the generic loop to
        rounding; None for a model without a kernel or a batch that is not finite (the generic
        loop then runs, and reports a bad state as it always did)."""
        kernel = self.model.braking_kernel(self.deceleration, self.gains)
        if kernel is None or not (np.all(np.isfinite(X)) and np.all(np.isfinite(U_hold))):
            return None
        from secure3d.dynamics._braking_kernels import braking_rollout

        kind, params = kernel
        out = braking_rollout(
            kind,
            np.ascontiguousarray(X, dtype=float),
            np.ascontiguousarray(U_hold, dtype=float),
            n_hold,
            n_max,
            dt,
            np.asarray(params, dtype=float),
            REST_SPEED,
        )
        if not np.all(np.isfinite(out)):
            return None
        return np.ascontiguousarray(out.transpose(1, 0, 2))

    def at_rest(self, X: np.ndarray) -> np.ndarray:
        """Stopped: speed < 1e-3 m/s (and |omega| < 1e-3 rad/s, attitude settled to 1e-3 rad)."""
        return self.model.braking_at_rest(
            np.asarray(X, dtype=float), REST_SPEED, self.deceleration, self.gains
        )
