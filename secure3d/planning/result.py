"""What the planner returns: a status code plus a result record (never an exception for a solver
failure), in the style of toppra.

A :class:`PlanResult` carries the discretised trajectory of the NLP (the paper's eq. NLP), the camera
poses and reactive-set ellipsoids at every node (eq. ReactEllipse, E = {c + M z : |z| <= 1}), the
look-back assignment of the visibility constraint, timings and, for failures, which constraint
families are violated and by how much.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np


class PlanStatus(enum.Enum):
    """Outcome of a planning call."""

    SUCCESS = "success"
    INFEASIBLE = "infeasible"
    ITERATION_LIMIT = "iteration_limit"
    SOLVER_ERROR = "solver_error"
    INVALID_INPUT = "invalid_input"
    NOT_CERTIFIED = "not_certified"
    #: the plan call's wall-time budget (``PlannerOptions.plan_budget``) ran out
    TIME_BUDGET = "time_budget"
    #: a solve's plan is longer than the caller's ``max_final_time`` or ``route_time_limit``
    #: (``plan_problem``): not refined, re-solved or certified further, since the caller would
    #: not fly it
    TOO_SLOW = "too_slow"

    @property
    def ok(self) -> bool:
        return self is PlanStatus.SUCCESS


@dataclass(frozen=True)
class Violation:
    """The first point where a plan breaks the safety condition (paper's Definition of *safe*)."""

    time: float
    point: np.ndarray
    reason: str
    margin: float

    def __str__(self) -> str:
        p = np.array2string(np.asarray(self.point), precision=2, separator=", ")
        return f"t={self.time:.3f}s at {p}: {self.reason} (margin {self.margin:+.3f} m)"


@dataclass(frozen=True)
class Certificate:
    """Verdict of :func:`secure3d.certify` (independent of the NLP's constraint code).

    Attributes
    ----------
    ok : every checked manoeuvre point was observed earlier and clear of known obstacles.
    min_margin : smallest margin over all checks (m); negative means violated.
    min_visibility_margin, min_obstacle_margin : the same split by family (m).
    first_violation : earliest violation in time, or None.
    n_samples : number of trajectory times checked; n_points : manoeuvre points checked.
    views : what observed each manoeuvre point of the sampled plan (its order, see
        :class:`~secure3d.planning.certificate.SampledPlan`): the sample whose camera saw it with a
        clear sight cone, -1 the start region, -2 not judged (before ``t_from``) or failing, -3 - j
        frame j of those taken before the plan (``PlanningProblem.past_views``).
    sampled : that sampled plan (:class:`~secure3d.planning.certificate.SampledPlan`: sample
        times, manoeuvre points, camera poses), so the views can be re-checked later
        (:func:`~secure3d.planning.recertify.views_after_adding`).
    """

    ok: bool
    min_margin: float
    min_visibility_margin: float
    min_obstacle_margin: float
    first_violation: Violation | None
    n_samples: int
    n_points: int
    views: np.ndarray | None = field(default=None, compare=False, repr=False)
    sampled: object | None = field(default=None, compare=False, repr=False)

    def __str__(self) -> str:
        verdict = "CERTIFIED" if self.ok else "NOT CERTIFIED"
        s = (
            f"{verdict}: min margin {self.min_margin:+.3f} m (visibility"
            f" {self.min_visibility_margin:+.3f}, obstacles {self.min_obstacle_margin:+.3f}),"
            f" {self.n_samples} times, {self.n_points} manoeuvre points"
        )
        if self.first_violation is not None:
            s += f"; first violation {self.first_violation}"
        return s


@dataclass(frozen=True, eq=False)
class WarmStart:
    """What a replan from a plan starts from: the solver's primal-dual solution and the structure
    it belongs to.

    Attributes
    ----------
    key : the NLP's structure key (:func:`secure3d.planning.nlp_cache.nlp_key`): multipliers are
        reused only by an NLP with the same key.
    w : (n_w,) float, the decision vector; lam_x : (n_w,), lam_g : (n_g,) its multipliers.
    L : (K, S, 6) float, the obstacle duals per node and slot.
    assignment : K ints, the look-back assignment (-1 = the start region).
    slots : (K, S, 6) float, the obstacle boxes in each node's slots.
    T : final time (s); X : (K, nx) states; U : (K, nu) controls.
    grid : (K,) node times as fractions of T, or None (evenly spaced).
    """

    key: tuple
    w: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    L: np.ndarray
    assignment: tuple[int, ...]
    slots: np.ndarray
    T: float
    X: np.ndarray
    U: np.ndarray
    grid: np.ndarray | None

    def __getitem__(self, name: str) -> object:
        """``warm["w"]``: the read of the dict this record replaces (its keys are the fields)."""
        if name not in self.__dataclass_fields__:
            raise KeyError(name)
        return getattr(self, name)


@dataclass(frozen=True, eq=False)
class PlanResult:
    """A planned trajectory and everything known about how it was obtained.

    Attributes
    ----------
    status, message : outcome and a one-line reason.
    planner : ``"secure"`` or ``"baseline"``.
    model_name : vehicle model.
    times : (K,) float, node times (s); states : (K, nx); controls : (K, nu).
    camera_rotations : (K, 3, 3) world-from-optical; camera_origins : (K, 3).
    positions : (K, 3) body-centre positions; speeds : (K,) speed (m/s).
    ellipsoid_centers : (K, 3), ellipsoid_shapes : (K, 3, 3): reactive sets at the nodes.
    lookback : (K,) int, node j whose frustum must contain node i's reactive set; -1 = the start
        region. lookback_rule : ``"fixed"`` or ``"adaptive"`` (which one produced the plan).
    build_time, solve_time : seconds spent building the NLP and inside the solver.
    iterations : solver iterations (summed over look-back rounds).
    violations : constraint family -> worst violation (m or unit of the family), for failures.
    certificate : the independent check of the returned trajectory (None if not run).
    rejections : the certificate's verdicts on the solver successes it rejected before this result
        (secure planner; each re-solved with tightened rows), oldest first: empty when the first
        solution certified (issue 16's first-try rate).
    route_length : length (m) of the route through the belief that the solver started from (the
        cold guess's graph-search path, from the start to the goal); NaN when it started from an
        earlier plan (warm) or had no guess (invalid input, no path). A closed loop judges detours
        by it (:func:`secure3d.simulation.modes.detour_reason`): the straight line to a goal behind
        a wall says nothing about how far the robot must go round.
    """

    status: PlanStatus
    message: str
    planner: str
    model_name: str
    times: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    camera_rotations: np.ndarray
    camera_origins: np.ndarray
    ellipsoid_centers: np.ndarray
    ellipsoid_shapes: np.ndarray
    positions: np.ndarray
    speeds: np.ndarray
    lookback: np.ndarray
    lookback_rule: str
    build_time: float
    solve_time: float
    iterations: int
    solver: str = "ipopt"
    violations: dict[str, float] = field(default_factory=dict)
    certificate: Certificate | None = None
    warm: WarmStart | None = field(default=None, repr=False)
    rejections: tuple[Certificate, ...] = field(default=(), repr=False)
    route_length: float = float("nan")

    @property
    def ok(self) -> bool:
        return self.status.ok

    def to_dict(self) -> dict[str, object]:
        """The plan's outcome as JSON-ready data (no arrays): status, final time, solver figures
        and the certificate's verdict and margins."""
        cert = self.certificate
        return {
            "planner": self.planner,
            "model": self.model_name,
            "status": self.status.value,
            "message": self.message,
            "final_time": finite_or_none(self.final_time) if self.ok else None,
            "nodes": int(len(self.times)),
            "solver": self.solver,
            "build_time": float(self.build_time),
            "solve_time": float(self.solve_time),
            "iterations": int(self.iterations),
            "certificate_rejections": len(self.rejections),
            "certificate": None
            if cert is None
            else {
                "ok": bool(cert.ok),
                "min_margin": finite_or_none(cert.min_margin),
                "min_visibility_margin": finite_or_none(cert.min_visibility_margin),
                "min_obstacle_margin": finite_or_none(cert.min_obstacle_margin),
                "first_violation": None
                if cert.first_violation is None
                else str(cert.first_violation),
            },
        }

    def rejection_note(self) -> str | None:
        """What the certificate rejected before this result, in one line (None: nothing): how many
        solutions, the first one's first violation and the node interval it falls in."""
        if not self.rejections:
            return None
        first = self.rejections[0].first_violation
        where = ""
        if first is not None and len(self.times) > 1:
            t = self.times
            k = int(np.clip(np.searchsorted(t, first.time, side="right") - 1, 0, len(t) - 2))
            at = (first.time - t[k]) / max(t[k + 1] - t[k], 1e-12)
            where = f" (between nodes {k} and {k + 1}, at {at:.2f} of the interval)"
        return f"rejected {len(self.rejections)} solution(s); the first: {first}{where}"

    @property
    def final_time(self) -> float:
        return float(self.times[-1]) if len(self.times) else float("nan")

    def summary(self) -> str:
        """One readable line."""
        cert = (
            ""
            if self.certificate is None
            else ("certified" if self.certificate.ok else "NOT certified")
        )
        return (
            f"{self.planner:8s} {self.status.value:15s} T={self.final_time:6.2f}s"
            f" build={self.build_time * 1e3:7.1f}ms solve={self.solve_time * 1e3:8.1f}ms"
            f" iters={self.iterations:4d} lookback={self.lookback_rule:8s} {cert}"
        )


def finite_or_none(value: float) -> float | None:
    """``value`` as a float, or None when it is not finite (JSON has no NaN or infinity)."""
    v = float(value)
    return v if np.isfinite(v) else None
