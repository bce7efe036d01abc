"""The node kernels: the per-node constraint families of the paper's eq. NLP as CasADi Functions.

Both transcriptions (IPOPT's collocation, :mod:`.collocation`, and fatrop's stage-wise form,
:mod:`.fatrop_transcription`) call these kernels on slices of their decision vectors, so both
enforce the same rows at the nodes: dynamics defect, model limits and world bounds, frustum and
start-region containment of the reactive set, obstacle clearance through separating planes
(:func:`node_kernels`), and the terminal rows (:func:`terminal_rows`). The transcriptions import
this module and never each other.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from secure3d.errors import ConfigError
from secure3d.planning import constraints as cons
from secure3d.planning.problem import PlanningProblem

__all__ = [
    "NodeKernels",
    "camera_dims",
    "camera_state_indices",
    "model_terminal_rows",
    "node_kernels",
    "read_indices",
    "terminal_rows",
]


@dataclass
class NodeKernels:
    """CasADi Functions for the per-node constraint families, built once per problem shape.

    Calling them on slices of the decision vector (rather than rebuilding expressions in Python for
    every node) keeps the transcription fast; each carries its rows' family names and bounds.
    """

    dyn: ca.Function
    path: ca.Function
    path_rows: list[tuple[str, float, float]]
    vis: ca.Function
    start: ca.Function
    obs_view: ca.Function
    obs_start: ca.Function
    obs_base: ca.Function
    obs_view_rows: list[tuple[str, float, float]]
    obs_start_rows: list[tuple[str, float, float]]
    obs_base_rows: list[tuple[str, float, float]]
    #: the kernels' derivative Functions (see :func:`assembled_derivatives`), built on first use
    derivatives: dict = field(default_factory=dict)


def _rows_function(
    name: str, inputs: list[ca.SX], rows: list[cons.Row]
) -> tuple[ca.Function, list]:
    expr = ca.vertcat(*[r[1] for r in rows]) if rows else ca.SX(0, 1)
    meta = [(r[0], float(r[2]), float(r[3])) for r in rows]
    return ca.Function(name, inputs, [expr]), meta


def node_kernels(problem: PlanningProblem) -> NodeKernels:
    """Build the per-node constraint Functions of ``problem`` (any look-back assignment)."""
    model, family, o = problem.model, problem.family, problem.options
    nx, nu, S = model.nx, model.nu, o.obstacle_slots
    xi, xj, ui = ca.SX.sym("xi", nx), ca.SX.sym("xj", nx), ca.SX.sym("ui", nu)
    xk1, uk1, um = ca.SX.sym("xk1", nx), ca.SX.sym("uk1", nu), ca.SX.sym("um", nu)
    h = ca.SX.sym("h")
    boxes, lams = ca.SX.sym("boxes", 6 * S), ca.SX.sym("lams", 6 * S)
    lo, hi = ca.SX.sym("lo", 3), ca.SX.sym("hi", 3)

    # dynamics defect between nodes k and k+1 (trapezoidal or Hermite-Simpson, compressed form)
    fk, fk1 = model.f(xi, ui), model.f(xk1, uk1)
    if o.collocation == "hermite_simpson":
        xm = 0.5 * (xi + xk1) + h / 8 * (fk - fk1)
        defect = xk1 - xi - h / 6 * (fk + 4 * model.f(xm, um) + fk1)
    else:
        defect = xk1 - xi - h / 2 * (fk + fk1)
    dyn = ca.Function("dyn", [xi, ui, xk1, uk1, um, h], [defect])

    # model limits and world bounds (only the coordinates that depend on the state)
    r = model.body_radius
    path_rows: list[cons.Row] = []
    g = model.path_constraints(xi, ui)
    path_rows += [("limits", g[d], -ca.inf, 0.0) for d in range(g.shape[0])]
    pos = model.position(xi)
    for d in range(3):
        if ca.depends_on(pos[d], xi):
            path_rows.append(("bounds", pos[d], problem.bounds_lo[d] + r, problem.bounds_hi[d] - r))
    path, path_meta = _rows_function("path", [xi, ui], path_rows)

    c, M = family.ellipsoid(xi)
    R_cam, o_cam = model.camera_pose(xj)
    vis, _ = _rows_function(
        "vis", [xi, xj], cons.frustum_rows(c, M, R_cam, o_cam, problem.frustum, o.margin)
    )
    start, _ = _rows_function("start", [xi, lo, hi], cons.start_region_rows(c, M, lo, hi, o.margin))

    view_rows, start_rows, base_rows = [], [], []
    for s_ in range(S):
        box, lam = boxes[6 * s_ : 6 * s_ + 6], lams[6 * s_ : 6 * s_ + 6]
        dual = cons.dual_norm_row(lam)
        clear = cons.ellipsoid_clearance_row(c, M, box, lam, o.margin)
        view_rows += [dual, clear]
        if o.occlusion:
            view_rows.append(cons.point_clearance_row("occlusion", o_cam, 0.0, box, lam, o.margin))
        start_rows += [dual, clear]
        # The same separating plane for this node and the next keeps the straight segment between
        # them clear too (the plane's side is an affine function of the position).
        base_rows += [
            dual,
            cons.point_clearance_row("obstacle", pos, r, box, lam, o.margin),
            cons.point_clearance_row("obstacle", model.position(xk1), r, box, lam, o.margin),
        ]
    obs_view, view_meta = _rows_function("obs_view", [xi, xj, boxes, lams], view_rows)
    obs_start, start_meta = _rows_function("obs_start", [xi, boxes, lams], start_rows)
    obs_base, base_meta = _rows_function("obs_base", [xi, xk1, boxes, lams], base_rows)
    return NodeKernels(
        dyn,
        path,
        path_meta,
        vis,
        start,
        obs_view,
        obs_start,
        obs_base,
        view_meta,
        start_meta,
        base_meta,
    )


def camera_dims(model: object) -> tuple[int, ...]:
    """State coordinates the camera pose (rotation and origin) depends on."""
    x = ca.SX.sym("x", model.nx)
    R, o = model.camera_pose(x)
    pose = ca.vertcat(ca.vec(R), o)
    return tuple(d for d in range(model.nx) if ca.depends_on(pose, x[d]))


def model_terminal_rows(model: object, x_end: ca.SX) -> list[ca.SX]:
    """Extra terminal equalities so the robot is really at rest (angular rates of planar models)."""
    return list(model.rest_residuals(x_end))


def terminal_rows(model: object, x_end: ca.SX, goal: ca.SX, w: ca.SX) -> list[ca.SX]:
    """Equalities for "at rest at the goal" at the last node (each row is zero there).

    Parameters
    ----------
    model : vehicle model; x_end : (nx,) the last node's state; goal : (3,) the goal position;
    w : the decision vector (a position coordinate that does not depend on it gets no row).

    Returns
    -------
    The goal-position rows, then :func:`~secure3d.planning.constraints.rest_rows`, then
    :func:`model_terminal_rows`, in that order.
    """
    pos_end = model.position(x_end)
    rows = [pos_end[d] - goal[d] for d in range(3) if ca.depends_on(pos_end[d], w)]
    return rows + cons.rest_rows(model, x_end) + model_terminal_rows(model, x_end)


def read_indices(fun: ca.Function, arg: int, nx: int) -> np.ndarray:
    """Entries of input ``arg`` (a state, length nx) that ``fun``'s outputs depend on.

    Returns
    -------
    (nc,) int, sorted.
    """
    args = [ca.SX.sym(f"a{i}", fun.sparsity_in(i)) for i in range(fun.n_in())]
    if args[arg].numel() != nx:
        raise ConfigError(f"read_indices: input {arg} of {fun.name()} is not a state of size {nx}")
    expr = ca.vertcat(*[ca.vec(out) for out in fun.call(args)])
    return np.array([d for d in range(nx) if ca.depends_on(expr, args[arg][d])], dtype=int)


def camera_state_indices(kernels: NodeKernels, nx: int) -> np.ndarray:
    """State entries of x_j that the visibility and occlusion kernels read (the camera pose's
    arguments): (nc,) int, sorted."""
    both = np.union1d(read_indices(kernels.vis, 1, nx), read_indices(kernels.obs_view, 1, nx))
    return both.astype(int)
