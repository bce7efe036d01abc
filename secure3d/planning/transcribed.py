"""What a transcription produces, whichever solver it is for: the layout of the decision vector
(:class:`NLPLayout`), the built NLP with its solver and row bookkeeping (:class:`TranscribedNLP`),
and the parameter vector and node grid they take. Both transcriptions
(:mod:`secure3d.planning.collocation`, :mod:`secure3d.planning.fatrop_transcription`) and the solve
loop (:mod:`secure3d.planning.solve`) read these; :mod:`.collocation` re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from secure3d.planning.problem import PlanningProblem, Solver

__all__ = [
    "NO_PARAMETER_MULTIPLIERS",
    "T_MAX",
    "T_MIN",
    "NLPLayout",
    "TranscribedNLP",
    "node_fractions",
    "parameter_vector",
    "selection_matrix",
    "viewing_states",
]

#: Bounds on the final time (s): below is numerically meaningless, above is a unit error.
T_MIN, T_MAX = 0.05, 300.0


@dataclass
class NLPLayout:
    """Where each variable block lives in the NLP's decision vector w."""

    K: int
    nx: int
    nu: int
    slots: int
    hermite: bool
    viewing: bool = False
    #: one dual per box axis and slot (the side comes as a parameter), else six
    one_sided: bool = False
    #: state coordinates the camera pose depends on (the viewing states hold only these)
    view_dims: tuple[int, ...] = ()
    #: the K-1 interval lengths, in units of T/(K-1), are the last parameters (else all 1)
    grid: bool = False
    i_T: int = 0
    i_X: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    i_U: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    i_Um: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    i_L: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    i_Y: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), int))
    n_w: int = 0

    def __post_init__(self) -> None:
        K, nx, nu, S = self.K, self.nx, self.nu, self.slots
        # Block order [T, X, U, Um, Lam, Y], each block column-major by node, so that CasADi can
        # view every block as one matrix (one graph node) and map the node kernels over its columns.
        n = 1
        self.i_X = (n + np.arange(K * nx)).reshape(K, nx)
        n += K * nx
        self.i_U = (n + np.arange(K * nu)).reshape(K, nu)
        n += K * nu
        n_m = (K - 1) if self.hermite else 0
        self.i_Um = (n + np.arange(n_m * nu)).reshape(n_m, nu)
        n += n_m * nu
        n_l = 3 if self.one_sided else 6
        self.i_L = (n + np.arange(K * S * n_l)).reshape(K, S, n_l)
        n += K * S * n_l
        n_y, n_d = (K, len(self.view_dims)) if self.viewing else (0, 0)
        self.i_Y = (n + np.arange(n_y * n_d)).reshape(n_y, n_d)
        n += n_y * n_d
        self.n_w = n

    def unpack(
        self, w: np.ndarray, sides: np.ndarray | None = None
    ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """(T, X, U, L) with L the (K, S, 6) duals; one-sided duals need their ``sides``."""
        w = np.asarray(w, dtype=float).ravel()
        return float(w[self.i_T]), w[self.i_X], w[self.i_U], self._six(w[self.i_L], sides)

    def _six(self, L: np.ndarray, sides: np.ndarray | None) -> np.ndarray:
        if not self.one_sided:
            return L
        if sides is None:
            raise ValueError("one-sided duals need the sides they were solved with")
        pos = np.asarray(sides, dtype=bool)
        return np.concatenate([np.where(pos, L, 0.0), np.where(pos, 0.0, L)], axis=-1)

    def pack(
        self,
        T: float,
        X: np.ndarray,
        U: np.ndarray,
        L: np.ndarray,
        Um: np.ndarray | None = None,
        assignment: tuple[int, ...] | None = None,
    ) -> np.ndarray:
        """The decision vector; ``L`` holds (K, S, 6) duals (folded to one side if one-sided)."""
        w = np.zeros(self.n_w)
        w[self.i_T] = T
        w[self.i_X] = X
        w[self.i_U] = U
        L = np.asarray(L, dtype=float)
        w[self.i_L] = L[..., :3] + L[..., 3:] if self.one_sided else L
        if self.hermite:
            w[self.i_Um] = 0.5 * (U[:-1] + U[1:]) if Um is None else Um
        if self.viewing and assignment is not None:
            w[self.i_Y] = viewing_states(X, assignment)[:, list(self.view_dims)]
        return w


def selection_matrix(assignment: tuple[int, ...]) -> np.ndarray:
    """(K, K) one-hot rows: S[i, j] = 1 where node i is seen from node j (zero row: start region)."""
    K = len(assignment)
    S = np.zeros((K, K))
    for i, j in enumerate(assignment):
        if j >= 0:
            S[i, j] = 1.0
    return S


def viewing_states(X: np.ndarray, assignment: tuple[int, ...]) -> np.ndarray:
    """(K, nx) state of the node each node is seen from (zeros for the start region)."""
    return selection_matrix(assignment) @ np.asarray(X, dtype=float)


@dataclass
class TranscribedNLP:
    """A built NLP: the solver, its layout, bounds, and per-family row indices of g."""

    key: tuple
    layout: NLPLayout
    solver: ca.Function
    g_fun: ca.Function
    lbg: np.ndarray
    ubg: np.ndarray
    families: dict[str, np.ndarray]
    n_p: int
    build_time: float
    #: rows that only hold for nodes seen from an earlier node / only for start-region nodes, and
    #: the node of every row (-1: not node-specific); used by :meth:`bounds_for`.
    view_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    start_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    row_node: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    warm_solver: ca.Function | None = None
    #: IPOPT's iteration callback (Ctrl-C); CasADi does not own Python callbacks, so the record does
    stop_callback: ca.Callback | None = None
    nlp: dict | None = None
    solver_name: str = "ipopt"
    solver_options: dict = field(default_factory=dict)

    def bounds_for(self, assignment: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """Row bounds (lbg, ubg) for a look-back assignment: a node's frustum and occlusion rows are
        switched off (lower bound -inf) where it lies in the start region, its start-region rows
        where it is seen from an earlier node."""
        if not len(self.row_node):
            return self.lbg, self.ubg
        is_view = np.asarray(assignment, dtype=int) >= 0
        node_view = np.where(self.row_node >= 0, is_view[np.maximum(self.row_node, 0)], False)
        node_start = (self.row_node >= 0) & ~node_view
        lbg = self.lbg.copy()
        lbg[(self.view_rows & node_start) | (self.start_rows & node_view)] = -np.inf
        return lbg, self.ubg

    def parameters(
        self,
        problem: PlanningProblem,
        slot_boxes: np.ndarray,
        assignment,
        sides: np.ndarray | None = None,
        grid: np.ndarray | None = None,
    ) -> np.ndarray:
        """The NLP's parameter vector (see :func:`parameter_vector`), then the dual sides
        (one-sided duals), the selection matrix (look-back as a parameter) and the interval
        ratios of the node time fractions ``grid`` (default, None: evenly spaced)."""
        parts = [parameter_vector(problem, slot_boxes)]
        if getattr(self.layout, "one_sided", False):
            if sides is None:
                raise ValueError("one-sided duals need their sides")
            parts.append(np.asarray(sides, dtype=float).ravel())
        if getattr(self.layout, "viewing", False):
            parts.append(selection_matrix(assignment).ravel(order="F"))
        if getattr(self.layout, "grid", False):
            K = self.layout.K
            parts.append(
                np.ones(K - 1) if grid is None else (K - 1) * np.diff(node_fractions(grid, K))
            )
        return np.concatenate(parts)

    def get_warm_solver(self) -> ca.Function:
        """Same NLP, solver options tuned for a warm start from a primal-dual guess."""
        if self.warm_solver is None:
            opts = dict(self.solver_options)
            if self.solver_name == Solver.IPOPT:
                # Measured on blind_corner (K=40, replan 0.1 s along the plan, 3 runs): 41
                # iterations with mu_init 1e-4 and pushes 1e-6; 28 with these settings.
                opts.update(
                    {
                        "ipopt.warm_start_init_point": "yes",
                        "ipopt.warm_start_bound_push": 1e-8,
                        "ipopt.warm_start_mult_bound_push": 1e-8,
                        "ipopt.warm_start_slack_bound_push": 1e-8,
                        "ipopt.mu_init": 1e-5,
                        "ipopt.tol": 1e-5,
                        # Warm replans were slower without the monotone fall-back.
                        "ipopt.adaptive_mu_globalization": "obj-constr-filter",
                    }
                )
            self.warm_solver = ca.nlpsol("secure3d_warm", self.solver_name, self.nlp, opts)
        return self.warm_solver


def node_fractions(times: np.ndarray, K: int) -> np.ndarray:
    """Node times (K,) as fractions of the last, checked: 0 first, 1 last, increasing."""
    t = np.asarray(times, dtype=float).ravel()
    if t.shape != (K,) or t[0] != 0.0 or t[-1] <= 0.0 or np.any(np.diff(t) <= 0.0):
        raise ValueError(f"node times must be {K} increasing values from 0, got {t}")
    return t / t[-1]


def parameter_vector(problem: PlanningProblem, slot_boxes: np.ndarray) -> np.ndarray:
    """NLP parameters: start box lo (3), hi (3), goal (3), slot boxes (K*S*6)."""
    return np.concatenate(
        [problem.start_region_lo, problem.start_region_hi, problem.goal, slot_boxes.ravel()]
    )


#: nlpsol options: no multipliers of the parameters (``lam_p``, which nothing here reads), so no
#: ``nlp_grad`` Function. CasADi builds it by default, by reverse mode over every row (173k
#: instructions for the closed loop's NLP), and evaluates it after every solve: nlpsol took
#: 0.11 s of the 0.42 s build, 0.014 s without. The solution is otherwise unchanged: x, f, g,
#: lam_x and lam_g come from the solver itself either way. (IPOPT only: CasADi 3.8.2's fatrop
#: interface aborts in free() without ``nlp_grad``.)
NO_PARAMETER_MULTIPLIERS = {"calc_lam_p": False, "no_nlp_grad": True}
