"""Direct collocation of the minimum-time problem (the paper's eq. NLP) into a CasADi NLP.

Decision variables, stage by stage: the final time T, states x_k and controls u_k at K nodes
(Hermite-Simpson adds midpoint controls), and one dual vector lam in R^6 per (node, obstacle slot).
Interval k lasts r_k T / (K - 1), the ratios r a parameter: all 1 (evenly spaced nodes, exactly the
uniform grid's arithmetic) for a cold solve; a warm replan keeps the previous plan's later nodes at
their times (:func:`~secure3d.planning.trajectory.remainder_keeping_nodes`). Obstacles enter as
*parameters* (a fixed number of box slots per node). The look-back assignment (which earlier
node's frustum must contain node i's reactive set) enters in one of two ways
(``PlannerOptions.lookback_encoding``):

- ``"structure"``: node i's frustum rows read x_j directly; one compiled NLP per assignment, cached;
- ``"parameter"``: a selection matrix ties each node's *viewing state* y_i to the earlier node it is
  assigned to (y_i = sum_j S_ij x_j, S a parameter, only the coordinates the camera pose depends
  on), and row bounds switch each node between the frustum rows and the start-region rows; one
  compiled NLP serves every assignment (the stage-wise fatrop transcription is always structural).

Sections, top to bottom as in CasADi's race_car example: variables, objective, dynamics, path
constraints, boundary conditions, obstacle and visibility constraints, solver.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from secure3d.planning.assembled_derivatives import KernelCall, assembled_nlp
from secure3d.planning.interrupt import stop_callback
from secure3d.planning.interval_rows import parametric_interval_rows, structure_interval_rows
from secure3d.planning.kernels import NodeKernels, camera_dims, node_kernels, terminal_rows
from secure3d.planning.nlp_cache import (  # noqa: F401  (NLPCache, the identities: re-exported)
    NLPCache,
    family_identity,
    model_identity,
    nlp_key,
    register_transcription,
    transcription,
)
from secure3d.planning.problem import Planner, PlanningProblem, Solver
from secure3d.planning.transcribed import (  # noqa: F401  (re-exported: the former home of these)
    NO_PARAMETER_MULTIPLIERS,
    T_MAX,
    T_MIN,
    NLPLayout,
    TranscribedNLP,
    node_fractions,
    parameter_vector,
    selection_matrix,
    viewing_states,
)

#: Symbol type in which the rows are written (the NLP the solver gets is an MX graph over them, see
#: ASSEMBLED_DERIVATIVES). Measured on blind_corner (K=40) with CasADi's own derivatives: an MX
#: transcription's Hessian costs ~18 ms per iteration, an SX one's ~1.5 ms.
SYM = ca.SX

#: Give IPOPT the NLP as a small MX graph over the node kernels, with the constraint Jacobian and
#: Lagrangian Hessian assembled from the kernels' derivatives
#: (:mod:`secure3d.planning.assembled_derivatives`), instead of one SX graph with CasADi's
#: whole-graph derivatives: same values to rounding, same sparsity, a build in ~0.1 s instead of
#: 0.7-0.9 s for the same assembly in one SX graph (benchmarks/results/nlp_iteration.md).
ASSEMBLED_DERIVATIVES = True
#: Largest KKT regularisation IPOPT's inertia correction tries for the secure planner (see
#: ``_solver_options``).
MAX_HESSIAN_PERTURBATION = 1e10


def _solver_options(problem: PlanningProblem, planner: str = "secure") -> tuple[str, dict]:
    o = problem.options
    opts = {
        "print_time": False,
        **NO_PARAMETER_MULTIPLIERS,
        "ipopt.print_level": 5 if o.verbose else 0,
        "ipopt.sb": "yes",
        "ipopt.max_iter": o.max_iter,
        "ipopt.tol": 1e-6,
        "ipopt.acceptable_tol": 1e-4,
        "ipopt.acceptable_iter": 5,
        "ipopt.acceptable_constr_viol_tol": 1e-5,
        "ipopt.max_wall_time": float(o.time_limit),
        "ipopt.mu_strategy": "adaptive",
        # The adaptive barrier update without its monotone fall-back mode. Measured over the ten
        # scenarios in maps/ (cold secure, warm replan, baseline; all still certified): total cold
        # secure solve time 58.1 s -> 9.3 s, baseline 8.4 s -> 2.3 s, warm replans unchanged (the
        # warm solver keeps IPOPT's default, below).
        "ipopt.adaptive_mu_globalization": "never-monotone-mode",
        "ipopt.linear_solver": "mumps",
    }
    if planner == Planner.SECURE:
        # No gradient-based row scaling for the secure NLP. Measured over the ten scenarios in
        # maps/ (cold, 1 run each, every plan certified): total cold secure solve 11.1 s -> 9.6 s,
        # blind_corner 0.29 s / 33 iterations -> 0.18 s / 21, six scenarios faster, three the
        # same, narrow_passage_50cm slower (0.39 -> 0.73 s); 8 hidden-obstacle flights 0.65x ->
        # 0.67x real time. The baseline stays scaled: unscaled, its solves took 6.5 s instead of
        # 2.5 s in all and planar_blind_corner's hit the iteration limit.
        opts["ipopt.nlp_scaling_method"] = "none"
        # A bound on IPOPT's inertia correction (default 1e20), so that one iteration of a
        # diverging solve cannot outlast the plan budget's reserve: each failed attempt refactors
        # the KKT matrix with 8x the regularisation, ~27 factorizations up to 1e20. A forest
        # campaign replan (variant 151, call 2) spent 2.4-3.2 s in one such iteration and ended at
        # 10.5-11.5 s against a 10 s budget; with 1e10 it ends at 8.7-8.9 s, in TIME_BUDGET as before.
        # Every shipped scenario's cold secure plan is the same with 1e10 or 1e6 (iterations and
        # final time). Not for the baseline: its 793-iteration cloud_server solve changes.
        opts["ipopt.max_hessian_perturbation"] = MAX_HESSIAN_PERTURBATION
    return "ipopt", opts


def build_nlp(
    problem: PlanningProblem,
    planner: str,
    assignment: tuple[int, ...],
    kernels: NodeKernels | None = None,
) -> TranscribedNLP:
    """Transcribe the problem for a given look-back assignment (tuple of K ints, -1 = start region).

    Every constraint family is one mapped call of its node kernel over the nodes it applies to, so
    the expression graph (and the solver set-up time) does not grow with K.
    With another ``options.solver`` (``"fatrop"``) that solver's transcription is built instead
    (:data:`secure3d.planning.nlp_cache.TRANSCRIPTIONS`).
    """
    if problem.options.solver != Solver.IPOPT:  # another transcription (nlp_cache.TRANSCRIPTIONS)
        return transcription(problem.options.solver).build(problem, planner, assignment, kernels)
    t0 = time.perf_counter()
    lay = _layout(problem, planner == Planner.SECURE)
    kern = kernels if kernels is not None else node_kernels(problem)
    v = _symbols(problem, lay)
    rows = _NLPRows()
    J = _objective(problem, v)
    _dynamics_rows(rows, kern, v)
    _path_rows(rows, kern, v)
    _terminal_rows(rows, problem, v)
    _obstacle_and_visibility_rows(rows, problem, kern, v, planner, assignment)
    return _transcribed(problem, planner, assignment, kern, v, J, rows, t0)


def _layout(problem: PlanningProblem, secure: bool) -> NLPLayout:
    """Where each variable sits in the decision vector (viewing states for look-backs passed as
    parameters, the secure planner's ``lookback_encoding="parameter"``)."""
    model, o = problem.model, problem.options
    K, nx, nu, S = o.nodes, model.nx, model.nu, o.obstacle_slots
    hermite = o.collocation == "hermite_simpson"
    parametric = secure and o.lookback_encoding == "parameter"
    return NLPLayout(
        K=K,
        nx=nx,
        nu=nu,
        slots=S,
        hermite=hermite,
        viewing=parametric,
        one_sided=o.one_sided_duals,
        view_dims=camera_dims(model) if parametric else (),
        grid=True,
    )


@dataclass
class _Symbols:
    """The NLP's symbols: decision vector ``w`` (final time ``T``, states ``X`` (nx, K), controls
    ``U`` (nu, K), midpoint controls ``Um`` (nu, K-1)), parameters ``p`` (start box, goal, slot
    boxes ``Boxes`` (6S, K), dual sides, look-back selection, interval ratios; ``n_*`` their sizes),
    the obstacle duals ``Lam`` (6S, K), the mean step ``h`` and the interval lengths ``steps``."""

    lay: NLPLayout
    w: ca.SX
    T: ca.SX
    X: ca.SX
    U: ca.SX
    Um: ca.SX
    p: ca.SX
    start_lo: ca.SX
    start_hi: ca.SX
    goal: ca.SX
    Boxes: ca.SX
    Lam: ca.SX
    h: ca.SX
    steps: ca.SX
    n_boxes: int
    n_sides: int
    n_sel: int
    n_p: int


@dataclass
class _NLPRows:
    """Constraint rows in the order they are added: each block (a :class:`KernelCall` or a column
    of SX rows), each row's family name and bounds, and its node (-1: none)."""

    parts: list = field(default_factory=list)
    meta: list[tuple[str, float, float]] = field(default_factory=list)
    row_node: list[int] = field(default_factory=list)

    def add(
        self,
        out: object,
        rows: list[tuple[str, float, float]],
        n_cols: int,
        nodes: list[int] | None = None,
    ) -> None:
        self.parts.append(out if isinstance(out, KernelCall) else ca.vec(out))
        self.meta.extend(rows * n_cols)
        self.row_node.extend(
            np.repeat(nodes, len(rows)) if nodes is not None else [-1] * (len(rows) * n_cols)
        )


def _symbols(problem: PlanningProblem, lay: NLPLayout) -> _Symbols:
    """Decision variables and parameters (see :class:`_Symbols`)."""
    K, nx, nu, S = lay.K, lay.nx, lay.nu, lay.slots
    hermite, parametric = lay.hermite, lay.viewing

    # ---- decision variables and parameters ----------------------------------------------------
    w = SYM.sym("w", lay.n_w)
    T = w[0]
    X = ca.reshape(w[int(lay.i_X[0, 0]) : int(lay.i_X[-1, -1]) + 1], nx, K)
    U = ca.reshape(w[int(lay.i_U[0, 0]) : int(lay.i_U[-1, -1]) + 1], nu, K)
    Um = (
        ca.reshape(w[int(lay.i_Um[0, 0]) : int(lay.i_Um[-1, -1]) + 1], nu, K - 1)
        if hermite
        else SYM.zeros(nu, K - 1)
    )
    n_boxes = K * S * 6
    n_sides = K * S * 3 if lay.one_sided else 0
    n_sel = K * K if parametric else 0
    n_p = 9 + n_boxes + n_sides + n_sel + K - 1
    p = SYM.sym("p", n_p)
    ratios = p[n_p - (K - 1) :].T  # (1, K-1) interval lengths in units of the mean step
    start_lo, start_hi, goal = p[0:3], p[3:6], p[6:9]
    Boxes = ca.reshape(p[9 : 9 + n_boxes], 6 * S, K)  # column k = [lo; hi] of each slot at node k
    L_w = w[int(lay.i_L[0, 0, 0]) : int(lay.i_L[-1, -1, -1]) + 1]
    if lay.one_sided:
        # lam = [side * mu; (1 - side) * mu] per slot: mu >= 0 on the box faces facing the node
        Mu = ca.reshape(L_w, 3 * S, K)
        Side = ca.reshape(p[9 + n_boxes : 9 + n_boxes + n_sides], 3 * S, K)
        Lam = ca.vertcat(
            *[
                blk
                for s_ in range(S)
                for blk in (
                    Side[3 * s_ : 3 * s_ + 3, :] * Mu[3 * s_ : 3 * s_ + 3, :],
                    (1 - Side[3 * s_ : 3 * s_ + 3, :]) * Mu[3 * s_ : 3 * s_ + 3, :],
                )
            ]
        )
    else:
        Lam = ca.reshape(L_w, 6 * S, K)
    h = T / (K - 1)  # the mean step
    steps = h * ratios
    return _Symbols(
        lay,
        w,
        T,
        X,
        U,
        Um,
        p,
        start_lo,
        start_hi,
        goal,
        Boxes,
        Lam,
        h,
        steps,
        n_boxes,
        n_sides,
        n_sel,
        n_p,
    )


def _objective(problem: PlanningProblem, v: _Symbols) -> ca.SX:
    """Minimum time (+ a small normalised effort term)."""
    model, o, K = problem.model, problem.options, v.lay.K
    T, U, h = v.T, v.U, v.h
    # ---- objective: minimum time (+ a small normalised effort term) -------------------------------
    u_mid = 0.5 * (model.u_lo + model.u_hi)
    u_scale = np.maximum(0.5 * (model.u_hi - model.u_lo), 1e-6)
    J = T + o.effort_weight * h * ca.sumsqr((U - ca.repmat(u_mid, 1, K)) / ca.repmat(u_scale, 1, K))
    return J


def _dynamics_rows(rows: _NLPRows, kern: NodeKernels, v: _Symbols) -> None:
    """Dynamics defects between consecutive nodes."""
    K, nx, add = v.lay.K, v.lay.nx, rows.add
    X, U, Um, steps = v.X, v.U, v.Um, v.steps
    # ---- dynamics defects ------------------------------------------------------------------------
    dyn = KernelCall(kern.dyn, [X[:, : K - 1], U[:, : K - 1], X[:, 1:], U[:, 1:], Um, steps], K - 1)
    add(dyn, [("dynamics", 0.0, 0.0)] * nx, K - 1)


def _path_rows(rows: _NLPRows, kern: NodeKernels, v: _Symbols) -> None:
    """Model limits and world bounds at nodes 1..K-1."""
    K, X, U, add = v.lay.K, v.X, v.U, rows.add
    # ---- path constraints: model limits and world bounds -----------------------------------------
    if kern.path_rows:
        add(KernelCall(kern.path, [X[:, 1:], U[:, 1:]], K - 1), kern.path_rows, K - 1)


def _terminal_rows(rows: _NLPRows, problem: PlanningProblem, v: _Symbols) -> None:
    """At rest at the goal (x(0) is fixed through the variable bounds)."""
    # ---- boundary conditions: x(0) fixed through variable bounds; at rest at the goal -------------
    for row in terminal_rows(problem.model, v.X[:, v.lay.K - 1], v.goal, v.w):
        rows.add(row, [("terminal", 0.0, 0.0)], 1)


def _obstacle_and_visibility_rows(
    rows: _NLPRows,
    problem: PlanningProblem,
    kern: NodeKernels,
    v: _Symbols,
    planner: str,
    assignment: tuple[int, ...],
) -> None:
    """The baseline's obstacle rows, or the secure planner's visibility and obstacle rows (eq. NLP)
    for a look-back assignment that is structure, or passed as parameters (viewing states)."""
    # ---- obstacles and visibility (eq. NLP: S_r(x_i) inside S_s(x_j), clear of Ĉ_obst) ----------
    if planner != Planner.SECURE:
        _baseline_obstacle_rows(rows, kern, v)
    elif not v.lay.viewing:
        _structure_visibility_rows(rows, problem, kern, v, assignment)
    else:
        _parametric_visibility_rows(rows, problem, kern, v)


def _baseline_obstacle_rows(rows: _NLPRows, kern: NodeKernels, v: _Symbols) -> None:
    """The baseline's rows: the segment from each node to the next clear of its obstacle slots."""
    K, X = v.lay.K, v.X
    X_next = ca.horzcat(X[:, 2:], X[:, K - 1])
    rows.add(
        KernelCall(kern.obs_base, [X[:, 1:], X_next, v.Boxes[:, 1:], v.Lam[:, 1:]], K - 1),
        kern.obs_base_rows,
        K - 1,
    )


def _structure_visibility_rows(
    rows: _NLPRows,
    problem: PlanningProblem,
    kern: NodeKernels,
    v: _Symbols,
    assignment: tuple[int, ...],
) -> None:
    """The secure planner's rows for an assignment compiled as structure: node i's frustum rows
    read x_j directly (or the start region's rows for j = -1)."""
    o, K, add = problem.options, v.lay.K, rows.add
    X, Boxes, Lam = v.X, v.Boxes, v.Lam
    nodes = list(range(1, K))
    view = [k for k in nodes if assignment[k] >= 0]
    start = [k for k in nodes if assignment[k] < 0]
    if view:
        Xi, Xj = X[:, view], X[:, [assignment[k] for k in view]]
        add(
            KernelCall(kern.vis, [Xi, Xj], len(view)),
            [("visibility", o.margin, ca.inf)] * problem.frustum.n_faces,
            len(view),
            view,
        )
        add(
            KernelCall(kern.obs_view, [Xi, Xj, Boxes[:, view], Lam[:, view]], len(view)),
            kern.obs_view_rows,
            len(view),
            view,
        )
    if start:
        Xs = X[:, start]
        n_s = len(start)
        add(
            KernelCall(
                kern.start, [Xs, ca.repmat(v.start_lo, 1, n_s), ca.repmat(v.start_hi, 1, n_s)], n_s
            ),
            [("start_region", o.margin, ca.inf)] * 6,
            n_s,
            start,
        )
        add(
            KernelCall(kern.obs_start, [Xs, Boxes[:, start], Lam[:, start]], n_s),
            kern.obs_start_rows,
            n_s,
            start,
        )
    if o.interval_rows:
        structure_interval_rows(add, kern, problem, X, Boxes, Lam, assignment)


def _parametric_visibility_rows(
    rows: _NLPRows, problem: PlanningProblem, kern: NodeKernels, v: _Symbols
) -> None:
    """The secure planner's rows for a look-back assignment passed as parameters.

    Viewing states: y_i = sum_j S_ij x_j over earlier nodes j (S a one-hot parameter row, or zero
    for a node in the start region). Linear coupling rows keep the nonlinear frustum rows local to
    (x_i, y_i), so the Hessian stays block-sparse for every assignment.
    """
    o, lay, K, nx, add = problem.options, v.lay, v.lay.K, v.lay.nx, rows.add
    X, w, p, Boxes, Lam = v.X, v.w, v.p, v.Boxes, v.Lam
    n_boxes, n_sides, n_sel = v.n_boxes, v.n_sides, v.n_sel
    nodes = list(range(1, K))
    dims = list(lay.view_dims)
    Yv = ca.reshape(w[int(lay.i_Y[0, 0]) : int(lay.i_Y[-1, -1]) + 1], len(dims), K)
    Sel = ca.reshape(p[9 + n_boxes + n_sides : 9 + n_boxes + n_sides + n_sel], K, K)
    link = ca.horzcat(*[Yv[:, i] - ca.mtimes(X[dims, :i], Sel[i, :i].T) for i in nodes])
    add(link, [("viewing_state", 0.0, 0.0)] * len(dims), len(nodes), nodes)
    # the full viewing state, zero in the coordinates the camera pose does not depend on
    Y = SYM.zeros(nx, K)
    for r_, d in enumerate(dims):
        Y[d, :] = Yv[r_, :]
    Xi, Yi, Bi, Li = X[:, 1:], Y[:, 1:], Boxes[:, 1:], Lam[:, 1:]
    add(
        KernelCall(kern.vis, [Xi, Yi], K - 1),
        [("visibility", o.margin, ca.inf)] * problem.frustum.n_faces,
        K - 1,
        nodes,
    )
    add(
        KernelCall(
            kern.start,
            [Xi, ca.repmat(v.start_lo, 1, K - 1), ca.repmat(v.start_hi, 1, K - 1)],
            K - 1,
        ),
        [("start_region", o.margin, ca.inf)] * 6,
        K - 1,
        nodes,
    )
    # [dual, clear, occlusion] per slot; occlusion rows are switched off for start nodes
    add(KernelCall(kern.obs_view, [Xi, Yi, Bi, Li], K - 1), kern.obs_view_rows, K - 1, nodes)
    if o.interval_rows and K > 2:
        parametric_interval_rows(add, kern, problem, X, Y, Boxes, Lam, nodes)


def _transcribed(
    problem: PlanningProblem,
    planner: str,
    assignment: tuple[int, ...],
    kern: NodeKernels,
    v: _Symbols,
    J: ca.SX,
    rows: _NLPRows,
    t0: float,
) -> TranscribedNLP:
    """The solver (assembled derivatives, Ctrl-C callback) and the record solve.py reads."""
    w, p, n_p, lay = v.w, v.p, v.n_p, v.lay
    parts, meta, row_node = rows.parts, rows.meta, rows.row_node
    names = [m_[0] for m_ in meta]
    lbg = np.array([m_[1] for m_ in meta])
    ubg = np.array([m_[2] for m_ in meta])
    families = {n: np.flatnonzero(np.array(names) == n) for n in dict.fromkeys(names)}
    names_a = np.array(names)

    solver_name, opts = _solver_options(problem, planner)
    assembled = assembled_nlp(w, p, J, parts, kern.derivatives) if ASSEMBLED_DERIVATIVES else None
    if assembled is not None:
        nlp = assembled.nlp
        opts["jac_g"], opts["hess_lag"] = assembled.jac_g, assembled.hess_lag
    else:  # one SX graph, CasADi's own derivatives
        g = ca.vertcat(*[part.rows() if isinstance(part, KernelCall) else part for part in parts])
        nlp = {"x": w, "p": p, "f": J, "g": g}
    stop = None
    if solver_name == Solver.IPOPT:
        stop = stop_callback(w.numel(), len(meta), p.numel(), int(lay.i_T))
        opts["iteration_callback"] = stop  # Ctrl-C stops the solve (planning/interrupt.py)
    solver = ca.nlpsol(f"secure3d_{planner}", solver_name, nlp, opts)
    g_fun = solver.get_function("nlp_g")  # the rows as the solver evaluates them (no new graph)
    key = nlp_key(problem, planner, assignment)
    return TranscribedNLP(
        key=key,
        layout=lay,
        solver=solver,
        g_fun=g_fun,
        lbg=lbg,
        ubg=ubg,
        families=families,
        n_p=n_p,
        build_time=time.perf_counter() - t0,
        nlp=nlp,
        solver_name=solver_name,
        solver_options=opts,
        view_rows=np.isin(names_a, ["visibility", "occlusion"]),
        start_rows=names_a == "start_region",
        row_node=np.array(row_node, dtype=int),
        stop_callback=stop,
    )


register_transcription("ipopt", build_nlp, node_kernels)
