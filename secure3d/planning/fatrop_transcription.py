"""A stage-wise transcription of the planner's NLP (the paper's eq. NLP) that fatrop can solve.

fatrop (shipped in the casadi wheel) factorises the KKT system of an optimal-control problem by a
Riccati recursion. CasADi's ``structure_detection="auto"`` finds that structure only when
(DESIGN.md section 4, "Discretisation"):

- the decision vector is ordered stage by stage, ``w = [z_0, v_0, z_1, v_1, ..., z_{K-1}, v_{K-1}]``
  (z: states, v: controls);
- the constraint rows are ordered ``[gap_0, path_0, gap_1, path_1, ..., gap_{K-2}, path_{K-2},
  path_{K-1}]``; each gap-closing row reads ``z_{k+1}[i] - F_i(z_k, v_k) = 0`` (z_{k+1}[i] enters
  with coefficient +1 and no other entry of z_{k+1} appears) and every path row depends on one
  stage only;
- the Lagrangian Hessian is block-diagonal by stage (the interface silently drops coupling blocks).

The collocation transcription (:mod:`.collocation`) has none of this: T is one global variable, the
trapezoidal defect is implicit in x_{k+1}, and the visibility row of node i reads the camera of an
earlier node j. Here stage k carries

``z_k = [x_k, u_k, T_k, r_k]``
    the model state; the control at node k (a state, because controls are linear in time between
    nodes: the reading of :func:`secure3d.planning.trajectory.interpolate`, which the certificate
    and the tracker use); a copy of the final time (``T_{k+1} = T_k``); and a shift register
    ``r_k = (c(x_{k-1}), c(x_{k-2}), ..., c(x_{k-D}))`` of the last D nodes' entries that later
    rows read;
``v_k = [u_{k+1}, lam]``
    the next node's control (absent at the last stage) and the obstacle duals of the node(s) whose
    rows live in stage k.

Dynamics: ``x_{k+1}`` is the explicit RK4 integral (:data:`RK4_SUBSTEPS` steps) over
h = T_k / (K - 1) of ``xdot = f(x, u(t))`` with u linear from u_k to u_{k+1}; for the point mass
(a chain of integrators) this is exact, so a fatrop plan and an IPOPT (trapezoidal) plan differ
only by the collocation error of the latter. The register shifts, ``r_{k+1} = (c(x_k), r_k[0],
..., r_k[D-2])``, so rows that read an earlier node stay stage-local:

- secure planner: the visibility and occlusion rows of node i with look-back j = i - s
  (1 <= s <= D) read ``r_i[s - 1]``; c(x) holds the entries the camera pose depends on (position
  and yaw for the point mass, position and attitude quaternion for the quadrotor), D is the
  largest look-back span;
- baseline: node k's rows keep the segment from p_k to p_{k+1} clear with node k's duals; they
  live in stage k+1 (reading p_k from ``r_{k+1}[0]``, D = 1, c(x) = the position) and node k's
  duals with them, except the last node's, which only reads itself.

c(x) is found from the kernels' sparsity, not assumed; carrying the whole state instead would cost
D * nx states per stage, and fatrop's Riccati recursion grows with the cube of the stage size.

The constraint rows are the same :class:`~secure3d.planning.kernels.NodeKernels` as IPOPT's
(limits, bounds, frustum, start region, obstacle duals), so both solvers enforce the same
guarantees at the nodes. Differences from :func:`~secure3d.planning.collocation.build_nlp`:

- the control-dependent limit rows also hold at node 0 (u_0 acts over the first interval; the
  collocation transcription leaves u_0 inside its box only);
- the register is as deep as the longest look-back D of the assignment: the paper's fixed rule
  j = i - D, or the adaptive rule limited to spans <= ``PlannerOptions.max_span``
  (:data:`~secure3d.planning.problem.FATROP_MAX_SPAN` unless set);
- ``collocation`` does not apply (the discretisation is RK4), so ``"hermite_simpson"`` is refused;
- ``time_limit`` is not enforced (fatrop has no wall-clock limit; ``max_iter`` is), and fatrop
  takes no multiplier warm start (a warm replan starts from the previous primal only).

Cost: fatrop factorises every stage densely, and the 6 * obstacle_slots duals are stage controls
(48 with 8 slots), so its time per iteration grows quickly with the slots; the casadi wheel's
BLASFEO is built for TARGET_GENERIC (no AVX2/FMA kernels) on top of that.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from secure3d.errors import ConfigError
from secure3d.planning.kernels import (
    NodeKernels,
    camera_state_indices,
    node_kernels,
    read_indices,
    terminal_rows,
)
from secure3d.planning.nlp_cache import nlp_key, register_transcription
from secure3d.planning.problem import Planner, PlanningProblem
from secure3d.planning.result import PlanStatus
from secure3d.planning.transcribed import TranscribedNLP

#: RK4 steps per node interval. One is exact for the point mass (piecewise-cubic positions). For
#: the quadrotor (the only nonlinear dynamics) at h = 0.115 s and full body rates, the largest state
#: error against a tight scipy integration was measured at 8e-3 with one step and 5e-4 with two
#: (fourth order: x16 per halving; tests/planning/test_fatrop.py checks the order).
RK4_SUBSTEPS = 2

#: Convergence tolerance. fatrop measures the unscaled KKT error, IPOPT (tol 1e-6) a scaled one
#: whose dual part is divided by the multipliers' size. With 1e-6 on blind_corner fatrop's baseline
#: never met it (it stopped at the acceptable level) and the secure solve took 43 iterations
#: instead of 34, for the same T to 1e-4.
TOL, ACCEPTABLE_TOL, ACCEPTABLE_ITER = 1e-5, 1e-4, 5

#: Initial barrier parameter. fatrop's barrier update is monotone (IPOPT's here is adaptive), so
#: the start matters. Measured, one solve from the graph-search guess, baseline and secure planners
#: on six scenarios (blind_corner, its quadrotor version, warehouse, office_bt, narrow_passage_50cm,
#: planar_blind_corner): 901 / 714 / 565 iterations in all for 0.1 (fatrop's default) / 1e-2 /
#: 3e-3, all successful; 3e-3 cut blind_corner from 119 / 64 (baseline / secure) to 29 / 31.
MU_INIT = 3e-3

#: Linear cost on the duals of node 0 (x_0 is fixed, so no row uses them; the layout keeps them
#: for compatibility). Without it their only term is the barrier -mu log(lam), which pushes them
#: to infinity (IPOPT damps such variables with kappa_d; fatrop has no such option); with it they
#: settle at mu / weight and add about n * mu to the objective.
UNUSED_DUAL_WEIGHT = 1e-3


@dataclass
class StageLayout:
    """Where each variable block lives in the stage-ordered decision vector w.

    Offers the interface of :class:`~secure3d.planning.collocation.NLPLayout` that
    :mod:`secure3d.planning.solve` uses (``i_T``, ``i_X``, ``i_U``, ``i_L``, ``n_w``, ``pack``,
    ``unpack``, ``hermite``) plus the stage copies.

    Attributes
    ----------
    K, nx, nu, slots : nodes, model states, model controls, obstacle slots per node.
    depth : register depth D (0: no register).
    reg_idx : (nc,) int, the state entries c(x) the register carries.
    lam_stage : (K,) int, the stage holding node k's duals (default: stage k).
    i_T : index of T in stage 0 (the bounded copy; the gap rows make all copies equal).
    i_Ts : (K,) int, T_k. i_X : (K, nx). i_U : (K, nu), the state copies u_k.
    i_Unext : (K-1, nu), the control copies u_{k+1} in v_k. i_L : (K, slots, 6).
    i_R : (K, depth, nc), r_k[m] = c(x_{k-1-m}).
    stage_start : (K + 1,) int, first index of each stage (and n_w).
    n_z : states per stage.
    """

    K: int
    nx: int
    nu: int
    slots: int
    depth: int
    reg_idx: np.ndarray
    lam_stage: np.ndarray | None = None
    hermite: bool = False
    i_T: int = 0
    i_Ts: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    i_X: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    i_U: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    i_Unext: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    i_L: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    i_R: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    stage_start: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    n_z: int = 0
    n_w: int = 0

    def __post_init__(self) -> None:
        K, nx, nu, S, D = self.K, self.nx, self.nu, self.slots, self.depth
        self.reg_idx = np.asarray(self.reg_idx, dtype=int)
        stage = np.arange(K) if self.lam_stage is None else np.asarray(self.lam_stage, dtype=int)
        if stage.shape != (K,) or stage.min() < 0 or stage.max() >= K:
            raise ConfigError(
                f"StageLayout.lam_stage: expected {K} stages in [0, {K}), got {stage}"
            )
        self.lam_stage = stage
        nc = len(self.reg_idx)
        self.n_z = nx + nu + 1 + D * nc
        n_next = np.full(K, nu)
        n_next[-1] = 0  # no next control after the last node
        n_lam = np.bincount(stage, minlength=K)
        start = np.concatenate([[0], np.cumsum(self.n_z + n_next + 6 * S * n_lam)])
        z0 = start[:-1, None]
        self.stage_start = start
        self.i_X = z0 + np.arange(nx)
        self.i_U = z0 + nx + np.arange(nu)
        self.i_Ts = start[:-1] + nx + nu
        self.i_T = int(self.i_Ts[0])
        self.i_R = (z0 + nx + nu + 1 + np.arange(D * nc)).reshape(K, D, nc)
        self.i_Unext = z0[:-1] + self.n_z + np.arange(nu)
        rank = np.array([np.count_nonzero(stage[:k] == stage[k]) for k in range(K)])
        first = start[stage] + self.n_z + n_next[stage] + 6 * S * rank
        self.i_L = (first[:, None] + np.arange(6 * S)).reshape(K, S, 6)
        self.n_w = int(start[-1])

    def register_values(self, X: np.ndarray) -> np.ndarray:
        """(K, D, nc) register contents implied by node states X (K, nx): r_k[m] = c(x_{k-1-m}),
        with the start state filling the slots before node 0."""
        k = np.arange(self.K)[:, None] - 1 - np.arange(self.depth)[None, :]
        return np.asarray(X, dtype=float)[np.maximum(k, 0)][..., self.reg_idx]

    def pack(
        self, T: float, X: np.ndarray, U: np.ndarray, L: np.ndarray, Um: np.ndarray | None = None
    ) -> np.ndarray:
        """Decision vector (n_w,) from T, X (K, nx), U (K, nu), L (K, slots, 6); every copy (T_k,
        u_{k+1}, the register) is filled consistently. ``Um`` is accepted for interface
        compatibility and ignored (no midpoint controls)."""
        w = np.zeros(self.n_w)
        U = np.asarray(U, dtype=float)
        w[self.i_Ts] = T
        w[self.i_X] = X
        w[self.i_U] = U
        w[self.i_Unext] = U[1:]
        w[self.i_L] = L
        w[self.i_R] = self.register_values(X)
        return w

    def unpack(self, w: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """(T, X (K, nx), U (K, nu), L (K, slots, 6)) from a decision vector; T is the last stage's
        copy (the objective's)."""
        w = np.asarray(w, dtype=float).ravel()
        return float(w[self.i_Ts[-1]]), w[self.i_X], w[self.i_U], w[self.i_L]


def rk4_foh(
    model: object, x: ca.SX, u0: ca.SX, u1: ca.SX, h: ca.SX, steps: int = RK4_SUBSTEPS
) -> ca.SX:
    """Explicit RK4 over one node interval of length h with the control linear from u0 to u1.

    Parameters
    ----------
    model : vehicle model with ``f(x, u)`` (numpy and CasADi).
    x : (nx,) state at the interval's start; u0, u1 : (nu,) controls at its ends; h : length (s).
    steps : RK4 steps per interval.

    Returns
    -------
    (nx,) state at the interval's end (same type as ``x``: CasADi or numpy).
    """
    dt = h / steps
    for i in range(steps):
        a, b = i / steps, (i + 0.5) / steps
        ua, ub, uc = u0 + a * (u1 - u0), u0 + b * (u1 - u0), u0 + (i + 1) / steps * (u1 - u0)
        k1 = model.f(x, ua)
        k2 = model.f(x + 0.5 * dt * k1, ub)
        k3 = model.f(x + 0.5 * dt * k2, ub)
        k4 = model.f(x + dt * k3, uc)
        x = x + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return x


#: fatrop's ``return_flag`` (solver.stats()["fatrop"]) in the names IPOPT uses. 0 and 1 are fatrop's
#: Success and MaxIterExceeded; 2 was measured to be the acceptable-level stop (tol_acceptable for
#: acceptable_iter iterations). CasADi's ``success`` is True for 0 only.
FATROP_FLAGS = {
    0: ("Solve_Succeeded", PlanStatus.SUCCESS),
    1: ("Maximum_Iterations_Exceeded", PlanStatus.ITERATION_LIMIT),
    2: ("Solved_To_Acceptable_Level", PlanStatus.SUCCESS),
}


def fatrop_status(stats: dict) -> tuple[PlanStatus, str]:
    """Status and message of a fatrop solve from ``solver.stats()`` (the feasibility of the
    returned point is checked separately by the caller)."""
    flag = int(stats.get("fatrop", {}).get("return_flag", -1))
    return FATROP_FLAGS.get(flag, (f"fatrop return flag {flag}", PlanStatus.SOLVER_ERROR))[::-1]


def check_fatrop_options(problem: PlanningProblem, planner: str) -> None:
    """Raise :class:`~secure3d.errors.ConfigError` for options this transcription cannot honour."""
    o = problem.options
    if o.collocation != "trapezoidal":
        raise ConfigError(
            f"solver 'fatrop' discretises with explicit RK4 (no collocation scheme); got "
            f"collocation={o.collocation!r}: leave it at 'trapezoidal' or use solver='ipopt'"
        )


def _solver_options(problem: PlanningProblem, equality: list[bool]) -> dict:
    o = problem.options
    return {
        "print_time": False,
        "structure_detection": "auto",
        "expand": True,
        "equality": equality,
        "fatrop": {
            "print_level": 5 if o.verbose else 0,
            "max_iter": o.max_iter,
            "tol": TOL,
            "mu_init": MU_INIT,
            "tol_acceptable": ACCEPTABLE_TOL,
            "acceptable_iter": ACCEPTABLE_ITER,
        },
    }


class _Rows:
    """Constraint rows collected family by family, each tagged with its stage, then put in the
    order fatrop's structure detection needs (gap rows of stage k, then its path rows)."""

    def __init__(self) -> None:
        self.exprs: list[ca.SX] = []
        self.names: list[str] = []
        self.lb: list[float] = []
        self.ub: list[float] = []
        self.stage: list[int] = []
        self.part: list[int] = []

    def add(
        self, out: ca.SX, rows: list[tuple[str, float, float]], stages: list[int], gap: bool = False
    ) -> None:
        """``out`` (len(rows), len(stages)): column c holds the rows of stage ``stages[c]``."""
        if not rows or not stages:
            return
        self.exprs.append(ca.vec(out))
        for k in stages:
            for name, lo, hi in rows:
                self.names.append(name)
                self.lb.append(lo)
                self.ub.append(hi)
                self.stage.append(k)
                self.part.append(0 if gap else 1)

    def ordered(self) -> tuple[ca.SX, np.ndarray, np.ndarray, list[str]]:
        order = np.lexsort((np.arange(len(self.stage)), self.part, self.stage))
        g = ca.vertcat(*self.exprs)[order.tolist()]
        names = [self.names[i] for i in order]
        return g, np.asarray(self.lb, float)[order], np.asarray(self.ub, float)[order], names


def build_fatrop_nlp(
    problem: PlanningProblem,
    planner: str,
    assignment: tuple[int, ...],
    kernels: NodeKernels | None = None,
) -> TranscribedNLP:
    """Transcribe the problem stage by stage for fatrop (see the module docstring).

    Parameters
    ----------
    problem : the planning problem; ``options.solver`` should be ``"fatrop"``.
    planner : ``"secure"`` or ``"baseline"``.
    assignment : (K,) look-back node per node, -1 = the start region (secure planner only).
    kernels : the problem's node kernels (built if None).

    Returns
    -------
    TranscribedNLP
        With a :class:`StageLayout`; its parameters are
        :func:`~secure3d.planning.collocation.parameter_vector`'s.

    Raises
    ------
    ConfigError
        For ``collocation="hermite_simpson"``.
    """
    t0 = time.perf_counter()
    check_fatrop_options(problem, planner)
    secure = planner == Planner.SECURE
    kern = kernels if kernels is not None else node_kernels(problem)
    v = _stage_variables(problem, _stage_layout(problem, secure, assignment, kern))
    rows = _Rows()
    J = _objective(problem, v)
    _gap_rows(rows, problem, v)
    _first_stage_rows(rows, kern, v)
    _path_rows(rows, kern, v)
    _terminal_rows(rows, problem, v)
    if secure:
        _visibility_rows(rows, problem, kern, v, assignment)
    else:
        _segment_rows(rows, kern, v)
    return _transcribed(problem, planner, assignment, v, J, rows, t0)


def _stage_layout(
    problem: PlanningProblem, secure: bool, assignment: tuple[int, ...], kern: NodeKernels
) -> StageLayout:
    """The stages' layout: the register holds what later stages read of earlier ones (the
    secure planner's camera states over the deepest look-back; the baseline's previous node)."""
    model, o = problem.model, problem.options
    K, nx, nu, S = o.nodes, model.nx, model.nu, o.obstacle_slots
    if len(assignment) != K:
        raise ConfigError(f"assignment: expected {K} look-back entries, got {len(assignment)}")
    spans = [k - j for k, j in enumerate(assignment) if secure and k > 0 and j >= 0]
    if any(s < 1 for s in spans):
        raise ConfigError(f"assignment: every look-back must be an earlier node, got {assignment}")
    if secure:
        depth = max(spans, default=0)
        reg_idx = camera_state_indices(kern, nx) if depth else np.zeros(0, int)
        lam_stage = np.arange(K)
    else:  # node k's segment rows (and duals) move to stage k+1, where p_k is r_{k+1}[0]
        depth, reg_idx = 1, read_indices(kern.obs_base, 0, nx)
        lam_stage = np.minimum(np.arange(K) + 1, K - 1)
        lam_stage[0] = 0
    return StageLayout(
        K=K, nx=nx, nu=nu, slots=S, depth=depth, reg_idx=reg_idx, lam_stage=lam_stage
    )


@dataclass
class _StageVariables:
    """The stage-wise NLP's symbols: the decision vector ``w`` and its blocks (X (nx, K), U (nu,
    K), L (6S, K) duals, Ts (1, K) final-time copies, Un (nu, K-1) next controls, R (depth*nc, K)
    registers), the parameters ``p`` and theirs, and ``scatter`` (nx, nc), which rebuilds a state
    from register entries (c(x) in place, zeros elsewhere: the kernels skip them)."""

    lay: StageLayout
    w: ca.SX
    X: ca.SX
    U: ca.SX
    L: ca.SX
    Ts: ca.SX
    Un: ca.SX
    R: ca.SX
    p: ca.SX
    start_lo: ca.SX
    start_hi: ca.SX
    goal: ca.SX
    Boxes: ca.SX
    scatter: ca.DM

    def block(self, idx: np.ndarray) -> ca.SX:
        """Columns c = w[idx[c]] (see :func:`_columns`)."""
        return _columns(self.w, idx)


def _stage_variables(problem: PlanningProblem, lay: StageLayout) -> _StageVariables:
    """Decision variables and parameters (see :class:`_StageVariables`)."""
    K, nx, S, reg_idx = lay.K, lay.nx, lay.slots, lay.reg_idx
    nc = len(reg_idx)
    scatter = ca.DM(ca.Sparsity.triplet(nx, nc, reg_idx.tolist(), list(range(nc))), 1.0)
    w = ca.SX.sym("w", lay.n_w)
    X, U, L = _columns(w, lay.i_X), _columns(w, lay.i_U), _columns(w, lay.i_L.reshape(K, 6 * S))
    Ts = _columns(w, lay.i_Ts[:, None])  # (1, K)
    Un = _columns(w, lay.i_Unext)  # (nu, K-1)
    p = ca.SX.sym("p", 9 + K * S * 6)
    R = _columns(w, lay.i_R.reshape(K, lay.depth * nc)) if lay.depth else ca.SX(0, K)
    Boxes = ca.reshape(p[9:], 6 * S, K)
    return _StageVariables(lay, w, X, U, L, Ts, Un, R, p, p[0:3], p[3:6], p[6:9], Boxes, scatter)


def _columns(w: ca.SX, idx: np.ndarray) -> ca.SX:
    """Columns c = w[idx[c]]: idx (n_cols, n_rows) -> SX (n_rows, n_cols)."""
    idx = np.asarray(idx, dtype=int)
    return ca.reshape(w[idx.ravel().tolist()], idx.shape[1], idx.shape[0])


def _objective(problem: PlanningProblem, v: _StageVariables) -> ca.SX:
    """Final time (last stage) + the collocation transcription's effort term."""
    model, o, K = problem.model, problem.options, v.lay.K
    u_mid = 0.5 * (model.u_lo + model.u_hi)
    u_scale = np.maximum(0.5 * (model.u_hi - model.u_lo), 1e-6)
    effort = ca.sum1(((v.U - ca.repmat(u_mid, 1, K)) / ca.repmat(u_scale, 1, K)) ** 2)
    return (
        v.Ts[K - 1]
        + o.effort_weight / (K - 1) * ca.dot(v.Ts, effort)
        + UNUSED_DUAL_WEIGHT * ca.sum1(v.L[:, 0])
    )


def _gap_rows(rows: _Rows, problem: PlanningProblem, v: _StageVariables) -> None:
    """Gap-closing rows z_{k+1} - F(z_k, v_k): RK4 state, next control, T copy, register."""
    model, lay = problem.model, v.lay
    K, nx, nu, depth, reg_idx = lay.K, lay.nx, lay.nu, lay.depth, lay.reg_idx
    nc = len(reg_idx)
    xs, u0s, u1s, Tsym = (
        ca.SX.sym("x", nx),
        ca.SX.sym("u0", nu),
        ca.SX.sym("u1", nu),
        ca.SX.sym("T"),
    )
    rs = ca.SX.sym("r", depth * nc)
    r_next = ca.vertcat(xs[reg_idx.tolist()], rs[: (depth - 1) * nc]) if depth else ca.SX(0, 1)
    step = ca.Function(
        "stage_step",
        [xs, u0s, u1s, Tsym, rs],
        [ca.vertcat(rk4_foh(model, xs, u0s, u1s, Tsym / (K - 1)), u1s, Tsym, r_next)],
    )
    X, U, Ts, R = v.X, v.U, v.Ts, v.R
    Z_next = ca.vertcat(X[:, 1:], U[:, 1:], Ts[:, 1:], R[:, 1:])
    F = step.map(K - 1)(X[:, : K - 1], U[:, : K - 1], v.Un, Ts[:, : K - 1], R[:, : K - 1])
    gap_rows = [("dynamics", 0.0, 0.0)] * nx + [("stage_copy", 0.0, 0.0)] * (nu + 1 + depth * nc)
    rows.add(Z_next - F, gap_rows, list(range(K - 1)), gap=True)


def _first_stage_rows(rows: _Rows, kern: NodeKernels, v: _StageVariables) -> None:
    """Stage 0: the register filled with the start state, control limits over the first interval."""
    lay = v.lay
    depth, reg_idx = lay.depth, lay.reg_idx
    if depth:
        fill = ca.repmat(v.X[reg_idx.tolist(), 0], depth, 1)
        rows.add(v.R[:, 0] - fill, [("stage_copy", 0.0, 0.0)] * (depth * len(reg_idx)), [0])
    xs, us = ca.SX.sym("x", lay.nx), ca.SX.sym("u", lay.nu)
    path_sym = kern.path(xs, us)
    u_rows = [i for i in range(path_sym.shape[0]) if ca.depends_on(path_sym[i], us)]
    if u_rows:
        rows.add(
            kern.path(v.X[:, 0], v.U[:, 0])[u_rows, :], [kern.path_rows[i] for i in u_rows], [0]
        )


def _path_rows(rows: _Rows, kern: NodeKernels, v: _StageVariables) -> None:
    """Path constraints at nodes 1..K-1: model limits and world bounds."""
    K = v.lay.K
    if kern.path_rows:
        rows.add(kern.path.map(K - 1)(v.X[:, 1:], v.U[:, 1:]), kern.path_rows, list(range(1, K)))


def _terminal_rows(rows: _Rows, problem: PlanningProblem, v: _StageVariables) -> None:
    """Boundary conditions: at rest at the goal (last stage)."""
    K = v.lay.K
    terminal = terminal_rows(problem.model, v.X[:, K - 1], v.goal, v.w)
    rows.add(ca.vertcat(*terminal), [("terminal", 0.0, 0.0)] * len(terminal), [K - 1])


def _segment_rows(rows: _Rows, kern: NodeKernels, v: _StageVariables) -> None:
    """The baseline's obstacle rows, stage-local through the register: node k's segment
    p_k -> p_{k+1} in stage k+1, the last node's "segment" the node itself."""
    K, lay = v.lay.K, v.lay
    seg = list(range(1, K))[:-1]
    Xk = ca.mtimes(v.scatter, v.block(lay.i_R[[k + 1 for k in seg], 0]))
    Xk1 = v.X[:, [k + 1 for k in seg]]
    rows.add(
        kern.obs_base.map(len(seg))(Xk, Xk1, v.Boxes[:, seg], v.L[:, seg]),
        kern.obs_base_rows,
        [k + 1 for k in seg],
    )
    x_last = v.X[:, K - 1]
    rows.add(
        kern.obs_base(x_last, x_last, v.Boxes[:, K - 1], v.L[:, K - 1]), kern.obs_base_rows, [K - 1]
    )


def _visibility_rows(
    rows: _Rows,
    problem: PlanningProblem,
    kern: NodeKernels,
    v: _StageVariables,
    assignment: tuple[int, ...],
) -> None:
    """The secure planner's rows (eq. NLP), stage-local through the register: each node's reactive
    set inside its look-back camera's frustum (or the start region) and clear of the obstacles."""
    o, lay = problem.options, v.lay
    nodes = list(range(1, lay.K))
    view = [k for k in nodes if assignment[k] >= 0]
    start = [k for k in nodes if assignment[k] < 0]
    if view:
        cam = v.block(np.stack([lay.i_R[k, k - assignment[k] - 1] for k in view]))
        Xi, Xj = v.X[:, view], ca.mtimes(v.scatter, cam)
        n_faces = problem.frustum.n_faces
        rows.add(
            kern.vis.map(len(view))(Xi, Xj), [("visibility", o.margin, ca.inf)] * n_faces, view
        )
        rows.add(
            kern.obs_view.map(len(view))(Xi, Xj, v.Boxes[:, view], v.L[:, view]),
            kern.obs_view_rows,
            view,
        )
    if start:
        Xs = v.X[:, start]
        lo, hi = ca.repmat(v.start_lo, 1, len(start)), ca.repmat(v.start_hi, 1, len(start))
        rows.add(
            kern.start.map(len(start))(Xs, lo, hi),
            [("start_region", o.margin, ca.inf)] * 6,
            start,
        )
        rows.add(
            kern.obs_start.map(len(start))(Xs, v.Boxes[:, start], v.L[:, start]),
            kern.obs_start_rows,
            start,
        )


def _transcribed(
    problem: PlanningProblem,
    planner: str,
    assignment: tuple[int, ...],
    v: _StageVariables,
    J: ca.SX,
    rows: _Rows,
    t0: float,
) -> TranscribedNLP:
    """The rows in fatrop's order, the solver, and the record :mod:`secure3d.planning.solve` reads."""
    g, lbg, ubg, names = rows.ordered()
    families = {n: np.flatnonzero(np.array(names) == n) for n in dict.fromkeys(names)}
    nlp = {"x": v.w, "p": v.p, "f": J, "g": g}
    opts = _solver_options(problem, [bool(lo == hi) for lo, hi in zip(lbg, ubg, strict=True)])
    solver = ca.nlpsol(f"secure3d_{planner}_fatrop", "fatrop", nlp, opts)
    return TranscribedNLP(
        key=nlp_key(problem, planner, assignment),
        layout=v.lay,
        solver=solver,
        g_fun=ca.Function("g", [v.w, v.p], [g]),
        lbg=lbg,
        ubg=ubg,
        families=families,
        n_p=int(v.p.numel()),
        build_time=time.perf_counter() - t0,
        # fatrop takes no multiplier warm start: the "warm" solver is the same one (no rebuild)
        warm_solver=solver,
        nlp=nlp,
        solver_name="fatrop",
        solver_options=opts,
    )


register_transcription("fatrop", build_fatrop_nlp, node_kernels)
