"""The interface every reactive controller offers (``control(_batch)``, ``at_rest``,
``rollout(_batch)``), with the vectorised roll-out they share. The laws are in
:mod:`secure3d.reactive.controllers` (braking) and :mod:`secure3d.reactive.mpc` (the paper's MPC).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Any

import numpy as np

from secure3d.dynamics.base import VehicleModel
from secure3d.dynamics.integrate import _check_dt
from secure3d.errors import ConfigError

__all__ = ["REST_SPEED", "ReactiveController"]

#: Speed (m/s) and angular speed (rad/s) below which a manoeuvre counts as stopped.
REST_SPEED = 1e-3


class ReactiveController(ABC):
    """Common interface: ``control(_batch)``, ``at_rest``, ``rollout(_batch)``.

    Attributes
    ----------
    model : the vehicle.
    latency : reaction delay (s) during which the held control is applied.
    name : ``"braking"`` or ``"mpc"``.
    """

    name: str

    def __init__(self, model: VehicleModel, latency: float = 0.0):
        if not isinstance(model, VehicleModel):
            raise ConfigError(
                f"{type(self).__name__}.model: expected a VehicleModel, got {model!r}"
            )
        lat = float(latency)
        if not math.isfinite(lat) or lat < 0 or lat > 5.0:
            raise ConfigError(
                f"{type(self).__name__}.latency: must be in [0, 5] s, got {latency!r}"
            )
        self.model = model
        self.latency = lat

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.model.name}, latency={self.latency})"

    def config(self) -> dict[str, Any]:
        """Settings that shape the manoeuvres (stored with a fitted family, compared on load)."""
        return {"name": self.name, "latency": self.latency}

    @abstractmethod
    def control_batch(self, X: np.ndarray, dt: float = 0.01, **context: Any) -> np.ndarray:
        """Controls (N, nu) for states X (N, nx); ``dt`` is the step the control is held for."""

    def control(self, x: np.ndarray, dt: float = 0.01, **context: Any) -> np.ndarray:
        """Control (nu,) for one state x (nx,)."""
        batched = {
            k: (None if v is None else np.asarray(v, dtype=float)[None]) for k, v in context.items()
        }
        return self.control_batch(np.asarray(x, dtype=float)[None], dt, **batched)[0]

    @abstractmethod
    def at_rest(self, X: np.ndarray) -> np.ndarray:
        """(N,) bool: the manoeuvre has ended (speed and rates ~0)."""

    def default_t_max(self) -> float:
        """A horizon (s) long enough for every manoeuvre from within the limits to stop."""
        return self.latency + 8.0

    def _hold_controls(self, X0: np.ndarray, u_hold: np.ndarray | None) -> np.ndarray:
        if u_hold is None:
            return self.model.nominal_control(X0)
        U = np.broadcast_to(np.asarray(u_hold, dtype=float), (len(X0), self.model.nu))
        return np.array(U)

    def rollout_batch(
        self,
        X0: np.ndarray,
        dt: float = 0.01,
        t_max: float | None = None,
        u_hold: np.ndarray | None = None,
        **context: Any,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Roll out N manoeuvres at once.

        Parameters
        ----------
        X0 : (N, nx) float, states at the moment the unknown obstacle is detected.
        dt : integration step (s); controls are held over each step (RK4).
        t_max : longest manoeuvre (s); default :meth:`default_t_max`.
        u_hold : (nu,) or (N, nu) float, control held during the latency (default: the model's
            nominal control, i.e. coast / hover).
        **context : controller-specific per-manoeuvre data (MPC: ``obstacle_lo``,
            ``obstacle_hi`` (N, 3)).

        Returns
        -------
        t : (T,) float, times from detection (s).
        X : (N, T, nx) float. The run ends when all manoeuvres are at rest or at ``t_max``; those
            that stopped earlier keep being simulated under the law (and stay at rest). The
            latency is rounded up to whole steps.
        """
        dt = _check_dt(dt)
        X = self.model.project_state(np.array(X0, dtype=float, ndmin=2))
        if X.shape[1] != self.model.nx:
            raise ValueError(f"X0: expected (N, {self.model.nx}), got {X.shape}")
        t_max = self.default_t_max() if t_max is None else float(t_max)
        n_hold = math.ceil(self.latency / dt - 1e-9)
        n_max = max(n_hold, math.ceil(t_max / dt - 1e-9))
        U_hold = self._hold_controls(X, u_hold)
        traj = self._compiled_rollout(X, U_hold, n_hold, n_max, dt, context)
        if traj is None:
            traj = self._rollout_steps(X, U_hold, n_hold, n_max, dt, context)
        return dt * np.arange(traj.shape[1]), traj

    def _compiled_rollout(
        self,
        X: np.ndarray,
        U_hold: np.ndarray,
        n_hold: int,
        n_max: int,
        dt: float,
        context: dict[str, Any],
    ) -> np.ndarray | None:
        """The manoeuvres (N, T, nx) from one compiled loop, or None where the law has none (the
        generic loop :meth:`_rollout_steps` then runs)."""
        return None

    def _rollout_steps(
        self,
        X: np.ndarray,
        U_hold: np.ndarray,
        n_hold: int,
        n_max: int,
        dt: float,
        context: dict[str, Any],
    ) -> np.ndarray:
        """The generic loop of :meth:`rollout_batch`, one vectorised step at a time: (N, T, nx)."""
        states = [X]
        for k in range(n_max):
            if k < n_hold:
                U = U_hold
            else:
                rest = self.at_rest(X)
                if rest.all():
                    break
                U = self.control_batch(X, dt, **context)
            X = self.model.step_batch(X, U, dt)
            states.append(X)
        return np.stack(states, axis=1)

    def rollout(
        self,
        x0: np.ndarray,
        dt: float = 0.01,
        t_max: float | None = None,
        u_hold: np.ndarray | None = None,
        **context: Any,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One manoeuvre: ``t (T,)``, ``X (T, nx)`` (see :meth:`rollout_batch`)."""
        batched = {
            k: (None if v is None else np.asarray(v, dtype=float)[None]) for k, v in context.items()
        }
        uh = None if u_hold is None else np.asarray(u_hold, dtype=float)[None]
        t, X = self.rollout_batch(np.asarray(x0, dtype=float)[None], dt, t_max, uh, **batched)
        return t, X[0]
