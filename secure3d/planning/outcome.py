"""What a plan call returns: the checks before any solve, and the :class:`PlanResult` of a solve
or of a call that ends without one (used by :mod:`.solve`)."""

from __future__ import annotations

import numpy as np

from secure3d.planning import lookback as lb
from secure3d.planning.nlp_solve import FEASIBILITY_TOL, SolveCost, _Solve
from secure3d.planning.problem import Planner, PlanningProblem
from secure3d.planning.result import PlanResult, PlanStatus, WarmStart

__all__ = ["SAME_POINT", "failed_result", "precheck", "solution_result"]

#: A goal nearer the start than this (m) is the start: there is no trajectory to plan (the guess
#: of a path of no length has no direction).
SAME_POINT = 1e-6


def precheck(problem: PlanningProblem) -> str | None:
    """Reasons the problem cannot be solved at all (start/goal in obstacles or outside the map)."""
    r = problem.model.body_radius
    gap = float(np.linalg.norm(np.asarray(problem.goal)[:3] - problem.start_position))
    if gap < SAME_POINT:
        return f"goal {np.round(problem.goal, 3).tolist()} is the start ({gap:.1e} m away): nothing to plan"
    for label, p in (("start", problem.start_position), ("goal", problem.goal)):
        if np.any(p < problem.bounds_lo + r - 1e-9) or np.any(p > problem.bounds_hi - r + 1e-9):
            return f"{label} {np.round(p, 3).tolist()} is outside the map bounds (with the body radius {r} m)"
        if len(problem.boxes_lo):
            d = lb.min_box_distance_all(p[None], problem.boxes_lo, problem.boxes_hi)[0]
            if d.min() < r:
                k = int(np.argmin(d))
                return (
                    f"{label} {np.round(p, 3).tolist()} is inside a known obstacle (box"
                    f" {np.round(problem.boxes_lo[k], 2).tolist()}..{np.round(problem.boxes_hi[k], 2).tolist()},"
                    f" distance {d.min():.3f} m < body radius {r} m)"
                )
    return None


def failed_result(
    problem: PlanningProblem, planner: str, status: PlanStatus, message: str, build: float = 0.0
) -> PlanResult:
    """A call's result without a trajectory: ``status`` and ``message`` (empty arrays)."""
    model = problem.model
    z = np.zeros
    return PlanResult(
        status=status,
        message=message,
        planner=planner,
        model_name=model.name,
        times=z(0),
        states=z((0, model.nx)),
        controls=z((0, model.nu)),
        camera_rotations=z((0, 3, 3)),
        camera_origins=z((0, 3)),
        ellipsoid_centers=z((0, 3)),
        ellipsoid_shapes=z((0, 3, 3)),
        positions=z((0, 3)),
        speeds=z(0),
        lookback=z(0, int),
        lookback_rule=problem.options.lookback,
        build_time=build,
        solve_time=0.0,
        iterations=0,
        solver=problem.options.solver,
    )


def solution_result(
    problem: PlanningProblem, planner: str, s: _Solve, cost: SolveCost
) -> PlanResult:
    """The result of solve ``s`` (its status and message), with what the call's solves cost and
    what a warm replan needs."""
    model = problem.model
    K = problem.options.nodes
    times = s.T * (np.linspace(0.0, 1.0, K) if s.grid is None else s.grid)
    geo = lb.node_geometry(problem, s.X)
    speeds = np.linalg.norm(np.asarray(model.velocity(s.X), dtype=float), axis=1)
    return PlanResult(
        status=s.status,
        message=s.message,
        planner=planner,
        model_name=model.name,
        times=times,
        states=s.X,
        controls=s.U,
        camera_rotations=geo["R"],
        camera_origins=geo["o"],
        ellipsoid_centers=geo["C"],
        ellipsoid_shapes=geo["M"],
        positions=geo["P"],
        speeds=speeds,
        lookback=np.array(s.assignment if planner == Planner.SECURE else [-1] * K, dtype=int),
        lookback_rule=problem.options.lookback if planner == Planner.SECURE else "none",
        build_time=cost.build,
        solve_time=cost.solve,
        iterations=cost.iterations,
        solver=problem.options.solver,
        violations={k: v for k, v in s.violations.items() if v > FEASIBILITY_TOL},
        warm=WarmStart(
            key=s.nlp.key,
            w=s.w,
            lam_x=s.lam_x,
            lam_g=s.lam_g,
            L=s.L,
            assignment=s.assignment,
            slots=s.slots,
            T=s.T,
            X=s.X,
            U=s.U,
            grid=s.grid,
        ),
    )
