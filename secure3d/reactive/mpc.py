"""The paper's MPC reactive controller (section "Results"): penalises drift from the take-over
point and closeness to the obstacle, within the acceleration bound (point mass). Re-exported by
:mod:`secure3d.reactive.controllers`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np

from secure3d.dynamics.base import VehicleModel
from secure3d.dynamics.integrate import _check_dt
from secure3d.errors import ConfigError
from secure3d.reactive.controller_base import REST_SPEED, ReactiveController
from secure3d.validation import is_int, is_real

__all__ = ["MPCReactiveController", "MPCWeights", "obstacle_direction"]


@dataclass(frozen=True)
class MPCWeights:
    """Weights of the MPC reactive controller's cost (units make each term m^2 or m^2/s^2).

    Attributes
    ----------
    drift : weight of ``|p_k - p_takeover|^2``: stay near the take-over point.
    velocity : weight of ``|v_k|^2``: come to rest.
    terminal_velocity : weight of ``|v_N|^2``.
    effort : weight of ``|u_k|^2``.
    repulsion : weight of ``-n . (p_k - p_takeover)``, n the unit vector from the obstacle's
        nearest point to the vehicle: reward distance from the obstacle. At rest the vehicle
        settles ``repulsion / (2 drift)`` metres from the take-over point, away from the obstacle.
    """

    drift: float = 1.0
    velocity: float = 0.5
    terminal_velocity: float = 10.0
    effort: float = 0.02
    repulsion: float = 0.3

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            ok = is_real(v) and math.isfinite(v)
            if not ok or v < 0 or (f.name in ("drift", "effort") and v == 0):
                raise ConfigError(
                    f"MPCWeights.{f.name}: must be finite and >= 0 (> 0 for drift and "
                    f"effort), got {v!r}"
                )


def obstacle_direction(
    p: np.ndarray, lo: np.ndarray, hi: np.ndarray, fallback: np.ndarray
) -> np.ndarray:
    """Unit vectors (N, 3) from the nearest point of boxes [lo, hi] to points p (N, 3).

    ``fallback`` (N, 3) is used where a point lies inside its box.
    """
    d = p - np.clip(p, lo, hi)
    n = np.linalg.norm(d, axis=1, keepdims=True)
    return np.where(n > 1e-9, d / np.maximum(n, 1e-300), fallback)


class MPCReactiveController(ReactiveController):
    """The paper's MPC reactive controller, for the point mass.

    Every ``step`` seconds it solves, from the current state (p0, v0), over ``horizon`` steps of the
    exact zero-order-hold double integrator::

        min_u  sum_k w_d |p_k - p_to|^2 - w_r n . (p_k - p_to) + w_v |v_k|^2
               + w_T |v_N|^2 + w_u sum_k |u_k|^2        s.t.  u_k in the acceleration bound

    (p_to: the take-over point, n: unit vector from the obstacle to the vehicle), and applies u_0
    until the next solve. The problem is a strictly convex QP with a ball (or box) constraint per
    step. :meth:`control` solves it with CasADi/IPOPT (built once, warm-started);
    :meth:`rollout_batch` solves it for all manoeuvres at once with accelerated projected gradient
    (FISTA) in numpy, which the tests check against the CasADi solution.

    Parameters
    ----------
    model : a PointMass.
    horizon : number of MPC steps N.
    dt : MPC step and control period (s).
    weights : :class:`MPCWeights`.
    latency : reaction delay (s).
    tol : FISTA stopping tolerance on the control change (m/s^2).
    max_iter : FISTA iteration cap per solve.
    """

    name = "mpc"

    def __init__(
        self,
        model: VehicleModel,
        horizon: int = 15,
        dt: float = 0.1,
        weights: MPCWeights | None = None,
        latency: float = 0.0,
        tol: float = 1e-7,
        max_iter: int = 2000,
    ):
        super().__init__(model, latency)
        if not model.double_integrator:
            raise ConfigError(
                f"MPCReactiveController.model: implemented for point_mass, got {model.name!r}"
            )
        if not is_int(horizon) or not 2 <= horizon <= 200:
            raise ConfigError(
                f"MPCReactiveController.horizon: must be an integer in [2, 200], got {horizon!r}"
            )
        step = float(dt)
        if not math.isfinite(step) or not 0.005 <= step <= 1.0:
            raise ConfigError(f"MPCReactiveController.step: must be in [0.005, 1] s, got {step!r}")
        self.horizon, self.dt = horizon, step
        self.weights = MPCWeights() if weights is None else weights
        self.tol, self.max_iter = float(tol), int(max_iter)
        self._build_qp()
        self._nlp: Any = None
        self._warm: np.ndarray | None = None

    def config(self) -> dict[str, Any]:
        """Name, latency, horizon, MPC step and weights."""
        return {
            **super().config(),
            "horizon": self.horizon,
            "dt": self.dt,
            "weights": dataclasses.asdict(self.weights),
        }

    def default_t_max(self) -> float:
        """Latency + 8 s: braking plus the return to the settling point."""
        return self.latency + 8.0

    # -- the QP, per axis --------------------------------------------------------------------------
    def _build_qp(self) -> None:
        N, h, w = self.horizon, self.dt, self.weights
        k = np.arange(1, N + 1)[:, None]
        j = np.arange(N)[None, :]
        Gp = np.where(j < k, h * h * (k - j - 0.5), 0.0)
        Gv = np.where(j < k, h, 0.0)
        gN = Gv[-1]
        H = 2 * (
            w.drift * Gp.T @ Gp + w.velocity * Gv.T @ Gv + w.terminal_velocity * np.outer(gN, gN)
        )
        H += 2 * w.effort * np.eye(N)
        one = np.ones(N)
        self._Gp, self._Gv, self._H = Gp, Gv, H
        # Linear term b = bp * (p0 - p_to) + bv * v0 + bn * n, per axis.
        self._bp = 2 * w.drift * Gp.T @ one
        self._bv = (
            2 * w.drift * Gp.T @ (h * k[:, 0])
            + 2 * w.velocity * Gv.T @ one
            + 2 * w.terminal_velocity * gN
        )
        self._bn = -w.repulsion * Gp.T @ one
        self._lipschitz = float(np.linalg.eigvalsh(H).max())
        self._Hinv = np.linalg.inv(H)

    def _project(self, U: np.ndarray) -> np.ndarray:
        a = self.model.limits.max_accel
        if self.model.limits.accel_norm == "box":
            return np.clip(U, -a, a)
        n = np.sqrt(U[..., 0] ** 2 + U[..., 1] ** 2 + U[..., 2] ** 2)[..., None]
        return U * np.minimum(1.0, a / np.maximum(n, 1e-300))

    def _feasible(self, U: np.ndarray) -> np.ndarray:
        a = self.model.limits.max_accel * (1 + 1e-12)
        if self.model.limits.accel_norm == "box":
            return np.abs(U).max(axis=(1, 2)) <= a
        return (U[..., 0] ** 2 + U[..., 1] ** 2 + U[..., 2] ** 2).max(axis=1) <= a * a

    def solve_batch(
        self,
        X: np.ndarray,
        takeover: np.ndarray,
        normal: np.ndarray,
        warm: np.ndarray | None = None,
    ) -> tuple[np.ndarray, int]:
        """Solve the MPC QP for N states at once.

        The QP is strictly convex, so where the unconstrained minimiser ``-H^-1 b`` satisfies the
        acceleration bound it is the answer (one matrix product); the others are solved by FISTA
        (accelerated projected gradient) from ``warm``.

        Parameters
        ----------
        X : (N, 7) states. takeover : (N, 3) take-over points. normal : (N, 3) unit vectors from
            the obstacle to the vehicle.
        warm : (N, horizon, 3) initial guess (e.g. the previous plan shifted).

        Returns
        -------
        U : (N, horizon, 3) optimal accelerations. iterations : FISTA iterations used (0 if none).
        """
        p0, v0 = X[:, 0:3], X[:, 3:6]
        b = (
            self._bp[None, :, None] * (p0 - takeover)[:, None, :]
            + self._bv[None, :, None] * v0[:, None, :]
            + self._bn[None, :, None] * normal[:, None, :]
        )
        U = -np.matmul(self._Hinv, b)
        active = np.flatnonzero(~self._feasible(U))
        if active.size == 0:
            return U, 0
        start = U[active] if warm is None else warm[active]
        U[active], iterations = self._fista(b[active], self._project(start))
        return U, iterations

    def _fista(self, b: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, int]:
        Y, t = U.copy(), 1.0
        step = 1.0 / self._lipschitz
        for it in range(1, self.max_iter + 1):
            U_new = self._project(Y - step * (np.matmul(self._H, Y) + b))
            change = float(np.abs(U_new - U).max(initial=0.0))
            t_new = 0.5 * (1 + math.sqrt(1 + 4 * t * t))
            Y = U_new + ((t - 1) / t_new) * (U_new - U)
            U, t = U_new, t_new
            if change < self.tol:
                return U, it
        return U, self.max_iter

    # -- CasADi ------------------------------------------------------------------------------------
    def _casadi_solver(self) -> Any:
        if self._nlp is None:
            N, a = self.horizon, self.model.limits.max_accel
            u = ca.SX.sym("u", N, 3)
            par = ca.SX.sym("par", 12)
            p0, v0, pto, n = par[0:3].T, par[3:6].T, par[6:9].T, par[9:12].T
            k = ca.DM(np.arange(1, N + 1))
            w = self.weights
            P = ca.repmat(p0, N, 1) + self.dt * ca.mtimes(k, v0) + ca.mtimes(ca.DM(self._Gp), u)
            V = ca.repmat(v0, N, 1) + ca.mtimes(ca.DM(self._Gv), u)
            E = P - ca.repmat(pto, N, 1)
            cost = (
                w.drift * ca.sumsqr(E)
                - w.repulsion * ca.sum1(ca.mtimes(E, n.T))
                + w.velocity * ca.sumsqr(V)
                + w.terminal_velocity * ca.sumsqr(V[N - 1, :])
                + w.effort * ca.sumsqr(u)
            )
            x = ca.reshape(u, -1, 1)
            opts = {
                "ipopt.print_level": 0,
                "print_time": False,
                "ipopt.tol": 1e-12,
                "ipopt.sb": "yes",
            }
            if self.model.limits.accel_norm == "ball":
                g = ca.sum2(u * u) - a * a
                self._nlp = (
                    ca.nlpsol("mpc", "ipopt", {"x": x, "p": par, "f": cost, "g": g}, opts),
                    True,
                )
            else:
                self._nlp = (ca.nlpsol("mpc", "ipopt", {"x": x, "p": par, "f": cost}, opts), False)
        return self._nlp

    def solve(self, x: np.ndarray, takeover: np.ndarray, normal: np.ndarray) -> np.ndarray:
        """Solve the MPC for one state with CasADi/IPOPT: (horizon, 3) accelerations."""
        solver, has_g = self._casadi_solver()
        N, a = self.horizon, self.model.limits.max_accel
        par = np.concatenate([x[0:3], x[3:6], takeover, normal])
        args: dict[str, Any] = {
            "p": par,
            "x0": np.zeros(3 * N) if self._warm is None else self._warm,
        }
        if has_g:
            args.update(lbg=-np.inf, ubg=0.0)
        else:
            args.update(lbx=-a, ubx=a)
        sol = solver(**args)
        self._warm = np.array(sol["x"]).ravel()
        return self._warm.reshape(3, N).T

    def control_batch(self, X: np.ndarray, dt: float = 0.01, **context: Any) -> np.ndarray:
        """MPC controls (N, 4) (yaw rate 0), solved batched; context: ``obstacle_lo``,
        ``obstacle_hi`` (N, 3) and ``takeover`` (N, 3) (default: the current positions)."""
        X = np.asarray(X, dtype=float)
        lo, hi = context["obstacle_lo"], context["obstacle_hi"]
        takeover = context.get("takeover")
        takeover = X[:, 0:3] if takeover is None else takeover
        n = obstacle_direction(X[:, 0:3], lo, hi, -_unit(X[:, 3:6]))
        U, _ = self.solve_batch(X, takeover, n)
        return np.concatenate([U[:, 0, :], np.zeros((len(X), 1))], axis=1)

    def control(
        self,
        x: np.ndarray,
        obstacle: Any = None,
        takeover_point: Any = None,
        dt: float = 0.01,
        **_: Any,
    ) -> np.ndarray:
        """The MPC control (4,) for one state, solved with CasADi.

        Parameters
        ----------
        x : (7,) state.
        obstacle : (3,) point, or a pair/array ``(lo, hi)`` of box corners (2, 3).
        takeover_point : (3,) the take-over point (default: the current position).
        dt : unused (the MPC's own period is ``self.dt``); kept for the common interface.
        """
        x = np.asarray(x, dtype=float)
        lo, hi = _obstacle_box(obstacle)
        to = x[0:3] if takeover_point is None else np.asarray(takeover_point, dtype=float)
        n = obstacle_direction(x[None, 0:3], lo[None], hi[None], -_unit(x[None, 3:6]))[0]
        u = self.solve(x, to, n)[0]
        return np.concatenate([u, [0.0]])

    def rollout(
        self,
        x0: np.ndarray,
        obstacle: Any = None,
        takeover_point: Any = None,
        dt: float = 0.01,
        t_max: float | None = None,
        u_hold: np.ndarray | None = None,
        **context: Any,
    ) -> tuple[np.ndarray, np.ndarray]:
        """One MPC manoeuvre from x0 (7,) against ``obstacle`` (point (3,) or box (2, 3)).

        ``obstacle_lo``/``obstacle_hi`` may be given instead of ``obstacle``; ``takeover_point``
        defaults to x0's position. Returns ``t (T,)``, ``X (T, 7)``.
        """
        if obstacle is not None:
            context["obstacle_lo"], context["obstacle_hi"] = _obstacle_box(obstacle)
        if takeover_point is not None:
            context["takeover"] = np.asarray(takeover_point, dtype=float)
        return super().rollout(x0, dt, t_max, u_hold, **context)

    def at_rest(self, X: np.ndarray) -> np.ndarray:
        """Speed below 1e-3 m/s (the rollout also requires the applied control to vanish)."""
        return np.linalg.norm(np.asarray(X, dtype=float)[:, 3:6], axis=1) < REST_SPEED

    def rollout_batch(
        self,
        X0: np.ndarray,
        dt: float = 0.01,
        t_max: float | None = None,
        u_hold: np.ndarray | None = None,
        **context: Any,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Roll out N MPC manoeuvres (see :meth:`ReactiveController.rollout_batch`).

        Context: ``obstacle_lo``, ``obstacle_hi`` (N, 3) (required) and ``takeover`` (N, 3)
        (default: the initial positions, where the obstacle was detected). The MPC is re-solved
        every ``self.dt`` seconds (rounded to whole ``dt``), warm-started from its shifted previous
        plan; a manoeuvre ends when its speed and its control both vanish.
        """
        dt = _check_dt(dt)
        X = np.array(X0, dtype=float, ndmin=2)
        if "obstacle_lo" not in context or "obstacle_hi" not in context:
            raise ConfigError(
                "MPCReactiveController.rollout_batch: needs obstacle_lo and obstacle_hi (N, 3)"
            )
        lo = np.broadcast_to(np.asarray(context["obstacle_lo"], dtype=float), X[:, 0:3].shape)
        hi = np.broadcast_to(np.asarray(context["obstacle_hi"], dtype=float), X[:, 0:3].shape)
        takeover = context.get("takeover")
        takeover = X[:, 0:3].copy() if takeover is None else np.asarray(takeover, dtype=float)
        t_max = self.default_t_max() if t_max is None else float(t_max)
        n_hold = math.ceil(self.latency / dt - 1e-9)
        n_max = max(n_hold, math.ceil(t_max / dt - 1e-9))
        period = max(1, round(self.dt / dt))
        U_hold = self._hold_controls(X, u_hold)
        states, plan, U = [X], None, U_hold
        for k in range(n_max):
            if k >= n_hold and (k - n_hold) % period == 0:
                if (
                    plan is not None
                    and (self.at_rest(X) & (np.abs(U[:, :3]).max(axis=1) < REST_SPEED)).all()
                ):
                    break
                n = obstacle_direction(X[:, 0:3], lo, hi, -_unit(X[:, 3:6]))
                warm = None if plan is None else np.concatenate([plan[:, 1:], plan[:, -1:]], axis=1)
                plan, _ = self.solve_batch(X, takeover, n, warm)
                U = np.concatenate([plan[:, 0, :], np.zeros((len(X), 1))], axis=1)
            elif k < n_hold:
                U = U_hold
            X = self.model.step_batch(X, U, dt)
            states.append(X)
        traj = np.stack(states, axis=1)
        return dt * np.arange(traj.shape[1]), traj


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(n > 1e-12, v / np.maximum(n, 1e-300), 0.0)


def _obstacle_box(obstacle: Any) -> tuple[np.ndarray, np.ndarray]:
    if obstacle is None:
        raise ConfigError(
            "MPCReactiveController.control: an obstacle (point or (lo, hi) box) is required"
        )
    arr = np.asarray(obstacle, dtype=float)
    if arr.shape == (3,):
        return arr, arr
    if arr.shape == (2, 3) and np.all(arr[0] <= arr[1]):
        return arr[0], arr[1]
    raise ConfigError(
        "obstacle: expected a point (3,) or box corners (2, 3) with lo <= hi, "
        f"got shape {arr.shape}"
    )
