"""The interval rows of :attr:`~secure3d.planning.problem.PlannerOptions.interval_rows` (issue 16).

For every interval [t_i, t_i+1] (i in 1..K-2), node i+1's reactive set must also lie in node i's
view, with a clear sight and clear of node i's obstacle slots through node i's separating planes.
Both ends of the interval then satisfy one condition convex in the set's (centre, shape), so each
ellipsoid interpolated between them does too. The rows reuse the node kernels of
:func:`secure3d.planning.kernels.node_kernels` with shifted arguments; ``add`` is the
transcription's row collector ``add(out, rows, n_cols, nodes=None)``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import casadi as ca

from secure3d.planning.assembled_derivatives import KernelCall

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.kernels import NodeKernels
    from secure3d.planning.problem import PlanningProblem

__all__ = ["parametric_interval_rows", "structure_interval_rows"]


def structure_interval_rows(
    add: Callable,
    kern: NodeKernels,
    problem: PlanningProblem,
    X,
    Boxes,
    Lam,
    assignment: tuple[int, ...],
) -> None:
    """Rows of :attr:`PlannerOptions.interval_rows` for an assignment compiled as structure: for
    i in 1..K-2, node i+1's reactive set inside node i's view (frustum of node j(i) < i, with a
    clear sight through node i's separating planes) and clear of node i's slots through those
    planes; after a start-region node, only the clearance."""
    K, o = len(assignment), problem.options
    view = [k for k in range(1, K - 1) if assignment[k] >= 0]
    start = [k for k in range(1, K - 1) if assignment[k] < 0]
    if view:
        Xn, Xj = X[:, [k + 1 for k in view]], X[:, [assignment[k] for k in view]]
        n = len(view)
        rows = [("visibility", o.margin, ca.inf)] * problem.frustum.n_faces
        add(KernelCall(kern.vis, [Xn, Xj], n), rows, n)
        add(
            KernelCall(kern.obs_view, [Xn, Xj, Boxes[:, view], Lam[:, view]], n),
            kern.obs_view_rows,
            n,
        )
    if start:
        Xn, n = X[:, [k + 1 for k in start]], len(start)
        add(
            KernelCall(kern.obs_start, [Xn, Boxes[:, start], Lam[:, start]], n),
            kern.obs_start_rows,
            n,
        )


def parametric_interval_rows(
    add: Callable, kern: NodeKernels, problem: PlanningProblem, X, Y, Boxes, Lam, nodes: list[int]
) -> None:
    """The same rows for the look-back passed as a parameter: node i+1's set in the frustum of node
    i's viewing state Y_i, switched on and off with node i's own rows (``nodes`` = 1..K-1)."""
    K, o = X.shape[1], problem.options
    Xn, Yc, Bc, Lc, cur = (
        X[:, 2:],
        Y[:, 1 : K - 1],
        Boxes[:, 1 : K - 1],
        Lam[:, 1 : K - 1],
        nodes[:-1],
    )
    n = K - 2
    rows = [("visibility", o.margin, ca.inf)] * problem.frustum.n_faces
    add(KernelCall(kern.vis, [Xn, Yc], n), rows, n, cur)
    add(KernelCall(kern.obs_view, [Xn, Yc, Bc, Lc], n), kern.obs_view_rows, n, cur)
