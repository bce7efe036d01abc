"""One NLP solve: from a guess and a look-back assignment to the solver's answer.

:func:`_solve_once` picks the obstacle slots and duals near the guess, packs the start point,
parameters and bounds (:func:`_start_point`), runs the compiled solver (the warm-start one when it
is given multipliers of the same NLP) and reads its answer (:func:`_read_solution`): status,
solution, violations. :mod:`secure3d.planning.solve` chains such solves into a plan (look-back
rounds, slot refreshes, retries, certification).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from secure3d.errors import PlanningError
from secure3d.planning import lookback as lb
from secure3d.planning import slot_duals as sd
from secure3d.planning.fatrop_transcription import fatrop_status
from secure3d.planning.interrupt import (
    budget_spent,
    final_time_cap,
    interruptible,
    ran_away,
    stopped_for_budget,
)
from secure3d.planning.nlp_cache import NLPCache
from secure3d.planning.problem import Planner, PlanningProblem, Solver
from secure3d.planning.result import Certificate, PlanStatus
from secure3d.planning.transcribed import T_MAX, T_MIN, TranscribedNLP

#: Largest constraint violation accepted from a solver that reports success.
FEASIBILITY_TOL = 1e-4

#: Row families whose lower bound is a safety margin, tightened by the certificate's retries (not
#: the start region: it is often only just large enough for the first reactive sets).
MARGIN_FAMILIES = ("visibility", "obstacle", "occlusion")
#: The start region's rows (a reactive set inside the box observed around the start), tightened
#: only by the certificate's last retry (``START_TIGHTENING`` in :mod:`.judging`).
START_FAMILY = "start_region"

_IPOPT_STATUS = {
    "Solve_Succeeded": PlanStatus.SUCCESS,
    "Solved_To_Acceptable_Level": PlanStatus.SUCCESS,
    "Infeasible_Problem_Detected": PlanStatus.INFEASIBLE,
    "Maximum_Iterations_Exceeded": PlanStatus.ITERATION_LIMIT,
    "Maximum_WallTime_Exceeded": PlanStatus.ITERATION_LIMIT,
    "Maximum_CpuTime_Exceeded": PlanStatus.ITERATION_LIMIT,
}


@dataclass
class _Solve:
    """One NLP solve: solution arrays, status and bookkeeping."""

    status: PlanStatus
    message: str
    T: float
    X: np.ndarray
    U: np.ndarray
    L: np.ndarray
    w: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    nlp: TranscribedNLP
    assignment: tuple[int, ...]
    slots: np.ndarray
    violations: dict[str, float]
    solve_time: float
    iterations: int
    cached: bool
    #: time spent compiling the warm-start solver for this call (once per NLP; 0 otherwise)
    warm_build: float = 0.0
    #: node times as fractions of T; None: evenly spaced (a warm replan keeps earlier nodes)
    grid: np.ndarray | None = None
    #: the certificate's verdict on this solution, once judged (a passed one is not judged again)
    certificate: Certificate | None = None


@dataclass(frozen=True)
class SolveCost:
    """What solves cost, summed: seconds building NLPs (and warm-start solvers), seconds inside the
    solver, solver iterations."""

    build: float = 0.0
    solve: float = 0.0
    iterations: int = 0

    def __add__(self, other: SolveCost) -> SolveCost:
        return SolveCost(
            self.build + other.build, self.solve + other.solve, self.iterations + other.iterations
        )


#: The final time may not exceed this multiple of the initial guess's (a feasible-ish flight): keeps
#: IPOPT from wandering to absurd durations when it struggles.
T_GUESS_FACTOR = 3.0
#: A solution whose final time reaches this fraction of that upper bound is a stall, not a plan.
T_CAP_FRACTION = 0.99


def _variable_bounds(
    problem: PlanningProblem, nlp: TranscribedNLP, T_guess: float
) -> tuple[np.ndarray, np.ndarray]:
    lay, model = nlp.layout, problem.model
    lbx = np.full(lay.n_w, -np.inf)
    ubx = np.full(lay.n_w, np.inf)
    lbx[lay.i_T], ubx[lay.i_T] = T_MIN, min(T_MAX, max(T_GUESS_FACTOR * T_guess, 10.0))
    lbx[lay.i_X] = np.broadcast_to(model.x_lo, lay.i_X.shape)
    ubx[lay.i_X] = np.broadcast_to(model.x_hi, lay.i_X.shape)
    lbx[lay.i_X[0]] = problem.x0
    ubx[lay.i_X[0]] = problem.x0
    lbx[lay.i_U] = np.broadcast_to(model.u_lo, lay.i_U.shape)
    ubx[lay.i_U] = np.broadcast_to(model.u_hi, lay.i_U.shape)
    if lay.hermite:
        lbx[lay.i_Um] = np.broadcast_to(model.u_lo, lay.i_Um.shape)
        ubx[lay.i_Um] = np.broadcast_to(model.u_hi, lay.i_Um.shape)
    lbx[lay.i_L] = 0.0
    if getattr(lay, "viewing", False):
        lbx[lay.i_Y[0]] = ubx[lay.i_Y[0]] = 0.0  # node 0 is never judged: no viewing state
    return lbx, ubx


def _violations(
    nlp: TranscribedNLP, w: np.ndarray, p: np.ndarray, lbg: np.ndarray, ubg: np.ndarray
) -> dict[str, float]:
    g = np.asarray(nlp.g_fun(w, p)).ravel()
    excess = np.maximum(np.maximum(lbg - g, g - ubg), 0.0)
    return {
        name: float(excess[idx].max()) if len(idx) else 0.0 for name, idx in nlp.families.items()
    }


def _solve_once(
    problem: PlanningProblem,
    planner: str,
    assignment: tuple[int, ...],
    T: float,
    X: np.ndarray,
    U: np.ndarray,
    cache: NLPCache,
    L: np.ndarray | None = None,
    multipliers: tuple[tuple, np.ndarray, np.ndarray] | None = None,
    prev_slots: np.ndarray | None = None,
    extra_margin: float | np.ndarray = 0.0,
    grid: np.ndarray | None = None,
    left_out_limit: float | None = None,
    slots: np.ndarray | None = None,
) -> _Solve:
    """One NLP solve from the guess (T, X, U) on node time fractions ``grid`` (None: evenly
    spaced; only NLPs with a time-grid parameter take others). With ``left_out_limit`` the secure
    planner's slots also take every box within it of what a node constrains on X
    (:func:`~secure3d.planning.lookback.with_left_out_boxes`). ``slots`` (K, S, 6): these slots
    as they are, instead of a selection on X (then ``prev_slots`` and ``left_out_limit`` are
    unused)."""
    nlp, cached = cache.get(problem, planner, assignment)
    if not getattr(nlp.layout, "grid", False):
        grid = None
    start = _start_point(
        problem,
        planner,
        nlp,
        assignment,
        T,
        X,
        U,
        L,
        prev_slots,
        extra_margin,
        grid,
        left_out_limit,
        slots,
    )
    solver = nlp.solver
    warm_build = 0.0
    if multipliers is not None and multipliers[0] == nlp.key:
        start.args["lam_x0"], start.args["lam_g0"] = multipliers[1], multipliers[2]
        t_build = time.perf_counter()
        # a second nlpsol (same NLP, warm-start options) on first use
        solver = nlp.get_warm_solver()
        warm_build = time.perf_counter() - t_build
    run = _Run(nlp, start, assignment, cached, warm_build, grid)
    t0 = time.perf_counter()
    try:
        with interruptible():
            sol = solver(**start.args)
    except RuntimeError as exc:  # CasADi raises on evaluation errors (NaN in a function, ...)
        return _solver_error(exc, run, T, time.perf_counter() - t0)
    return _read_solution(run, sol, solver.stats(), time.perf_counter() - t0)


@dataclass(frozen=True)
class _Run:
    """One solve call's bookkeeping, which every :class:`_Solve` it ends in carries: the NLP, its
    start point, the look-back assignment, whether the NLP came from the cache, the seconds spent
    building a warm-start solver, and the node time grid."""

    nlp: TranscribedNLP
    start: _StartPoint
    assignment: tuple[int, ...]
    cached: bool
    warm_build: float
    grid: np.ndarray | None

    def solve(self, **fields: object) -> _Solve:
        """The :class:`_Solve` with this call's bookkeeping and the given result ``fields``."""
        return _Solve(
            nlp=self.nlp,
            assignment=self.assignment,
            slots=self.start.slots,
            cached=self.cached,
            warm_build=self.warm_build,
            grid=self.grid,
            **fields,
        )


def _solver_error(exc: Exception, run: _Run, T: float, solve_time: float) -> _Solve:
    """The solve that CasADi stopped with ``exc``: the start point, status SOLVER_ERROR."""
    start, nlp = run.start, run.nlp
    return run.solve(
        status=PlanStatus.SOLVER_ERROR,
        message=f"solver error: {exc}".splitlines()[0],
        T=T,
        X=start.X,
        U=start.U,
        L=start.L,
        w=start.args["x0"],
        lam_x=np.zeros(nlp.layout.n_w),
        lam_g=np.zeros(len(nlp.lbg)),
        violations={},
        solve_time=solve_time,
        iterations=0,
    )


@dataclass
class _StartPoint:
    """What one solve starts from: the guess as the NLP takes it (X with the start state, U within
    the limits, the slots' boxes and duals L), the solver's arguments (``x0``, ``p``, bounds) and
    the slots' dual sides (one-sided duals only)."""

    X: np.ndarray
    U: np.ndarray
    L: np.ndarray
    slots: np.ndarray
    sides: np.ndarray | None
    args: dict


def _start_point(
    problem: PlanningProblem,
    planner: str,
    nlp: TranscribedNLP,
    assignment: tuple[int, ...],
    T: float,
    X: np.ndarray,
    U: np.ndarray,
    L: np.ndarray | None,
    prev_slots: np.ndarray | None,
    extra_margin: float | np.ndarray,
    grid: np.ndarray | None,
    left_out_limit: float | None = None,
    given_slots: np.ndarray | None = None,
) -> _StartPoint:
    """Slots (``given_slots``, else a selection near the guess) and their duals, the packed
    initial point, parameters and bounds."""
    lay = nlp.layout
    X = np.array(X, dtype=float)
    X[0] = problem.x0
    U = np.clip(U, problem.model.u_lo, problem.model.u_hi)
    if given_slots is not None:
        slots = np.asarray(given_slots, dtype=float)
        prev_slots = None
    else:
        slots = lb.select_slots(problem, planner, X, assignment)
        slots = lb.keep_slot_positions(prev_slots, slots)
    if given_slots is None and left_out_limit is not None and planner == Planner.SECURE:
        slots = lb.with_left_out_boxes(problem, X, assignment, slots, left_out_limit)
    fresh = sd.initial_duals(problem, planner, X, slots, assignment)
    if L is None or prev_slots is None or L.shape != fresh.shape:
        L = fresh
    else:  # keep the previous duals only for slots that still hold the same box
        same = np.all(np.isclose(prev_slots, slots), axis=-1)
        L = np.where(same[..., None], L, fresh)
    if getattr(lay, "viewing", False):
        w0 = lay.pack(float(np.clip(T, T_MIN, T_MAX)), X, U, L, assignment=assignment)
    else:
        w0 = lay.pack(float(np.clip(T, T_MIN, T_MAX)), X, U, L)
    one_sided = getattr(lay, "one_sided", False)
    sides = sd.slot_sides(problem, planner, X, slots, assignment) if one_sided else None
    p = nlp.parameters(problem, slots, assignment, sides, grid)
    lbx, ubx = _variable_bounds(problem, nlp, T)
    lbg, ubg = nlp.bounds_for(assignment)
    lbg = tightened_bounds(nlp, lbg, extra_margin)
    args = {"x0": w0, "p": p, "lbx": lbx, "ubx": ubx, "lbg": lbg, "ubg": ubg}
    return _StartPoint(X, U, L, slots, sides, args)


def tightened_bounds(nlp: TranscribedNLP, lbg: np.ndarray, extra: float | np.ndarray) -> np.ndarray:
    """Lower row bounds ``lbg`` with the rows of :data:`MARGIN_FAMILIES` raised by ``extra``: one
    margin (m) for every such row, or one per node ((K,): the rows of node k by ``extra[k]``), or
    (2, K): per node, the first row for those families and the second for the start-region rows
    (:data:`START_FAMILY`, the last retry of the certificate's). Rows of no single node, and every
    row of an NLP that does not record its rows' nodes, take the largest. Rows switched off (-inf)
    stay off; nothing is ever lowered."""
    extra_arr = np.asarray(extra, dtype=float)
    K = nlp.layout.K
    if extra_arr.ndim > 1 and extra_arr.shape != (2, K):
        raise PlanningError(
            f"extra margin: one number, {K} (one per node) or (2, {K}), got {extra_arr.shape}"
        )
    if extra_arr.ndim == 2:
        lbg = _raised(nlp, lbg, extra_arr[0], MARGIN_FAMILIES)
        return _raised(nlp, lbg, extra_arr[1], (START_FAMILY,))
    return _raised(nlp, lbg, extra_arr, MARGIN_FAMILIES)


def _raised(
    nlp: TranscribedNLP, lbg: np.ndarray, extra: np.ndarray, families: tuple[str, ...]
) -> np.ndarray:
    """:func:`tightened_bounds` for one number or one per node (``extra``) and ``families``."""
    per_node = np.ndim(extra) > 0
    K = nlp.layout.K
    if per_node and extra.shape != (K,):
        raise PlanningError(
            f"extra margin: one number or {K} (one per node), got shape {extra.shape}"
        )
    if not np.all(np.isfinite(extra)):
        raise PlanningError(f"extra margin: must be finite (m), got {extra!r}")
    extra = np.maximum(extra, 0.0)
    if not np.any(extra):
        return lbg
    lbg = lbg.copy()
    nodes = nlp.row_node if per_node and len(nlp.row_node) == len(lbg) else None
    for name in families:
        idx = nlp.families.get(name, np.zeros(0, int))
        if nodes is None:
            lbg[idx] += extra.max()
        else:
            k = nodes[idx]
            lbg[idx] += np.where(k >= 0, extra[np.maximum(k, 0)], extra.max())
    return lbg


def _read_solution(run: _Run, sol: dict, stats: dict, solve_time: float) -> _Solve:
    """The solver's answer: the solution unpacked, its status (a converged solution that violates
    a row by more than :data:`FEASIBILITY_TOL` is INFEASIBLE) and its violations."""
    nlp, start = run.nlp, run.start
    a = start.args
    w = np.asarray(sol["x"]).ravel()
    lay = nlp.layout
    one_sided = getattr(lay, "one_sided", False)
    Ts, Xs, Us, Ls = lay.unpack(w, start.sides) if one_sided else lay.unpack(w)
    viol = _violations(nlp, w, a["p"], a["lbg"], a["ubg"])
    worst = max(viol.values(), default=0.0)
    rs = str(stats.get("return_status", "unknown"))
    stopped = rs == "User_Requested_Stop"
    if stopped and not (ran_away() or budget_spent() or stopped_for_budget()):
        # Ctrl-C (planning/interrupt.py): the user asked to stop, not to try the next start.
        raise KeyboardInterrupt("solve interrupted")
    status = _IPOPT_STATUS.get(
        rs, PlanStatus.SUCCESS if stats.get("success") else PlanStatus.SOLVER_ERROR
    )
    if stopped and ran_away():  # a final_time_watch (planning/interrupt.py)
        status = PlanStatus.ITERATION_LIMIT
        rs = f"stopped: the final time ran past {final_time_cap():.2f} s"
    elif stopped:
        status = PlanStatus.TIME_BUDGET
    if nlp.solver_name == Solver.FATROP:
        status, rs = fatrop_status(stats)
    if status is PlanStatus.SUCCESS and worst > FEASIBILITY_TOL:
        status = PlanStatus.INFEASIBLE
        rs += f" but constraints violated by {worst:.2e}"
    elif status is PlanStatus.SUCCESS and Ts >= T_CAP_FRACTION * a["ubx"][lay.i_T]:
        # stalled against the cap: paper_blind_corner's closed-loop baseline "solved" to T 9.98 s
        # under a 10 s cap (its 1.66 s plan solves from the next guess)
        status = PlanStatus.ITERATION_LIMIT
        rs += f" but the final time {Ts:.2f} s sits at its upper bound"
    return run.solve(
        status=status,
        message=rs,
        T=Ts,
        X=Xs,
        U=Us,
        L=Ls,
        w=w,
        lam_x=np.asarray(sol["lam_x"]).ravel(),
        lam_g=np.asarray(sol["lam_g"]).ravel(),
        violations=viol,
        solve_time=solve_time,
        iterations=int(stats.get("iter_count", 0)),
    )
