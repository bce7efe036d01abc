"""The constraint families of the secure NLP (the paper's eq. NLP), as CasADi expressions.

Each builder returns a list of ``(name, expression, lower, upper)`` rows so that the transcription
(:mod:`secure3d.planning.collocation`) can report violations per family. The numbers they encode
come from the geometry kernels (:mod:`secure3d.geometry`), whose numpy twins are tested against
independent methods; the certificate (:mod:`secure3d.planning.certificate`) shares none of this code.

Obstacles are axis-aligned boxes P = {y : A y <= b} with A = [I; -I], b = [hi; -lo]; each box in a
node's slot carries a dual vector lam >= 0 with |A^T lam| <= 1 (DESIGN.md section 4):

- body or reactive set E = {c + M z}: ``lam.(A c - b) - |M A^T lam| >= m``  (dist(E, P) >= m);
- line-of-sight hull conv({o} u E) (occlusion, beyond the paper): in addition ``lam.(A o - b) >= m``.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from secure3d.geometry.frustum import PinholeFrustum, frustum_halfspaces

Row = tuple[str, ca.SX, float, float]

#: Smoothing of the Euclidean norm in dual constraints: sqrt(|v|^2 + eps^2) >= |v| only adds
#: conservatism and keeps the gradient defined where A^T lam = 0 (DESIGN.md section 4).
NORM_EPS = 1e-4

BOX_NORMALS = np.vstack([np.eye(3), -np.eye(3)])


def _smooth_norm(v: ca.SX) -> ca.SX:
    return ca.sqrt(ca.sumsqr(v) + NORM_EPS**2)


def box_b(box: ca.SX) -> ca.SX:
    """b of the box parameter vector ``box = [lo (3), hi (3)]``: b = [hi; -lo]."""
    return ca.vertcat(box[3:6], -box[0:3])


def dual_norm_row(lam: ca.SX) -> Row:
    """|A^T lam|^2 <= 1 (the dual feasibility of the separation certificate)."""
    at_lam = lam[0:3] - lam[3:6]
    return ("dual_norm", ca.sumsqr(at_lam), -ca.inf, 1.0)


def point_clearance_row(
    name: str, p: ca.SX, radius: float, box: ca.SX, lam: ca.SX, margin: float
) -> Row:
    """Sphere of ``radius`` at ``p`` at least ``margin`` from the box: lam.(A p - b) >= radius + margin."""
    expr = ca.dot(lam, ca.mtimes(BOX_NORMALS, p) - box_b(box))
    return (name, expr, radius + margin, ca.inf)


def ellipsoid_clearance_row(c: ca.SX, M: ca.SX, box: ca.SX, lam: ca.SX, margin: float) -> Row:
    """Reactive set E = {c + M z} at least ``margin`` from the box (weak duality)."""
    at_lam = lam[0:3] - lam[3:6]
    expr = ca.dot(lam, ca.mtimes(BOX_NORMALS, c) - box_b(box)) - _smooth_norm(ca.mtimes(M, at_lam))
    return ("obstacle", expr, margin, ca.inf)


def frustum_rows(
    c: ca.SX, M: ca.SX, R_cam: ca.SX, o_cam: ca.SX, frustum: PinholeFrustum, margin: float
) -> list[Row]:
    """E inside the camera frustum of an earlier node: for every face, n.c + |M n| <= d - margin.

    This is the exact, smooth form of the paper's eq. NLPElipseInclude (support functions instead of
    mapping the frustum onto the unit ball).
    """
    A, b = frustum_halfspaces(R_cam, o_cam, frustum)
    rows = []
    for k in range(A.shape[0]):
        n = A[k, :].T
        rows.append(
            ("visibility", b[k] - ca.dot(n, c) - ca.norm_2(ca.mtimes(M, n)), margin, ca.inf)
        )
    return rows


def start_region_rows(c: ca.SX, M: ca.SX, lo: ca.SX, hi: ca.SX, margin: float) -> list[Row]:
    """E inside the observed start box: for each face +-e_d, the support c_d +- |M e_d| stays inside
    (exact for ellipsoids)."""
    rows = []
    for d in range(3):
        extent = ca.norm_2(M[:, d])
        rows.append(("start_region", hi[d] - c[d] - extent, margin, ca.inf))
        rows.append(("start_region", c[d] - lo[d] - extent, margin, ca.inf))
    return rows


#: Random states at which :func:`rest_rows` checks that a reduced rest condition is equivalent.
_REST_CHECKS = 16


def rest_rows(model: object, x: ca.SX) -> list[ca.SX]:
    """Rows that all vanish exactly when a vehicle in state ``x`` is at rest (velocity zero), with
    a Jacobian of full row rank there.

    The velocity's components are such rows for the point mass and the quadrotor (they are state
    entries). The differential drive's, ``(v cos(theta), v sin(theta), 0)``, are not: at v = 0 both
    rows have the gradient ``(cos(theta), sin(theta))`` in v alone, so the terminal Jacobian loses
    rank and IPOPT regularised its KKT matrix up to 1e18 (30-80 ms per iteration against 5 ms).
    Where the velocity is ``B(y) x_S`` for some state entries x_S (linear in them, zero when they
    are) with B of full column rank (checked at random states), ``x_S = 0`` is the same condition
    in fewer, well-conditioned rows: the diff drive's signed speed v = 0.
    """
    xs = ca.SX.sym("x", model.nx)
    vel = ca.vertcat(*[model.velocity(xs)[d] for d in range(3)])
    moving = [d for d in range(3) if ca.depends_on(vel[d], xs)]
    velocity_rows = [model.velocity(x)[d] for d in moving]
    entries = [d for d in range(model.nx) if ca.depends_on(vel, xs[d])]
    linear = [d for d in entries if ca.is_linear(vel, xs[d])]
    if not linear or len(linear) >= len(moving) or not ca.is_linear(vel, xs[linear]):
        return velocity_rows
    at_zero = ca.substitute(vel, xs[linear], ca.SX.zeros(len(linear)))
    if not all(at_zero[i].is_zero() for i in range(3)):
        return velocity_rows
    B = ca.Function("rest_B", [xs], [ca.jacobian(vel, xs[linear])])
    rng = np.random.default_rng(0)
    for _ in range(_REST_CHECKS):
        if np.linalg.matrix_rank(np.asarray(B(rng.uniform(-3.0, 3.0, model.nx)))) < len(linear):
            return velocity_rows
    return [x[d] for d in linear]
