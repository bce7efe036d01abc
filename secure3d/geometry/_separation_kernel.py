"""Compiled solver for the distance between a polytope and an ellipsoid or its line-of-sight hull.

Private to :mod:`secure3d.geometry.polytope`, which imports it lazily so that importing the geometry
package does not load numba.

Problem. ``H = conv({o} ∪ E)`` with ``E = {c + M z : |z| <= 1}`` and ``P = {y : A y <= b}``. A
point of ``H`` is ``o + theta (c - o) + M u`` with ``|u| <= theta <= 1`` (a second-order cone);
the plain ellipsoid is the special case ``o = c, theta = 1``. Then

    dist(H, P)^2 / 2 = min 1/2 |o + theta (c - o) + M u - y|^2   s.t.  |u| <= theta <= 1,  A y <= b.

Method. A primal log-barrier interior-point method (Boyd & Vandenberghe, ch. 11) in the 7 variables
``v = (u, theta, y)``. The slacks ``s = b - A y`` are variables of their own, so the start need
not lie inside ``P`` (infeasible-start Newton, B&V 10.3) and ``s`` keeps full relative precision
near active faces. On the central path ``mu = 1 / (t s)`` are the multipliers of ``A y <= b`` and
``A^T mu = e``, the primal residual; hence ``lam = mu / |A^T mu|`` is dual feasible (``lam >= 0``,
``|A^T lam| = 1``) and the dual objective of DESIGN.md section 4 at ``lam`` is a *certified lower
bound* on the distance, while ``|e|`` is an upper bound. Iterations stop when both agree within
``tol`` or when double precision stops improving them.
"""

from __future__ import annotations

import numpy as np
from numba import njit

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)

# Barrier parameter growth per outer iteration; 100 with loose centring measured fastest at equal
# accuracy (30 / 1e-9 took twice the Newton steps).
_T_GROWTH = 100.0
_CENTERING_TOL = 1e-6
_MAX_NEWTON = 400
_MAX_CENTERING = 30
# Duality gap of 1/2 dist^2 (relative to the squared scene size) below which double precision
# stops improving the bounds: further outer iterations would only burn time.
_GAP_FLOOR = 1e-17

#: Status codes returned by solve_separation (the wrapper turns them into GeometryError).
OK = 0
NOT_SYMMETRIC = 1
NOT_POSITIVE_DEFINITE = 2
ZERO_ROW = 3
EMPTY_POLYTOPE = 4
STATUS_MESSAGES = {
    NOT_SYMMETRIC: "ellipsoid shape: not symmetric",
    NOT_POSITIVE_DEFINITE: "ellipsoid shape: not positive definite",
    ZERO_ROW: "polytope: every row of A must be non-zero",
    EMPTY_POLYTOPE: "polytope: {A y <= b} is empty",
}


@njit(cache=True)
def _cholesky_solve(H, rhs, L, x):
    """Solve ``H x = rhs`` for a small SPD ``H`` into ``x`` (``L`` is scratch space).

    Adds a tiny ridge if roundoff has made ``H`` indefinite (possible at large barrier weights).
    """
    n = H.shape[0]
    scale = 0.0
    for i in range(n):
        scale = max(scale, abs(H[i, i]))
    ridge = 0.0
    for _attempt in range(8):
        ok = True
        for i in range(n):
            for j in range(i + 1):
                acc = H[i, j]
                if i == j:
                    acc += ridge
                for m in range(j):
                    acc -= L[i, m] * L[j, m]
                if i == j:
                    if acc <= 0.0:
                        ok = False
                        break
                    L[i, i] = np.sqrt(acc)
                else:
                    L[i, j] = acc / L[j, j]
            if not ok:
                break
        if ok:
            break
        ridge = max(ridge * 100.0, 1e-14 * scale + 1e-300)
    for i in range(n):
        acc = rhs[i]
        for m in range(i):
            acc -= L[i, m] * x[m]
        x[i] = acc / L[i, i]
    for i in range(n - 1, -1, -1):
        acc = x[i]
        for m in range(i + 1, n):
            acc -= L[m, i] * x[m]
        x[i] = acc / L[i, i]


@njit(cache=True)
def _residual(o, d, M, v, e):
    """``e = o + theta d + M u - y`` (the vector from the polytope point to the hull point)."""
    for j in range(3):
        e[j] = o[j] + v[3] * d[j] + M[j, 0] * v[0] + M[j, 1] * v[1] + M[j, 2] * v[2] - v[4 + j]


@njit(cache=True)
def _barrier_value(v, s, o, d, M, t, los, e):
    """Barrier objective ``t f + psi_cone + psi_theta - sum log s`` (inf outside the domain)."""
    logs = 0.0
    for i in range(s.shape[0]):
        if s[i] <= 0.0:
            return np.inf
        logs += np.log(s[i])
    uu = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    th = v[3]
    if los:
        w = th * th - uu
        if th <= 0.0 or th >= 1.0 or w <= 0.0:
            return np.inf
        psi = -np.log(w) - np.log(1.0 - th)
    else:
        w = 1.0 - uu
        if w <= 0.0:
            return np.inf
        psi = -np.log(w)
    _residual(o, d, M, v, e)
    return 0.5 * t * (e[0] * e[0] + e[1] * e[1] + e[2] * e[2]) + psi - logs


@njit(cache=True)
def _dual_bound(o, c, M, A, b, lam, los):
    """Dual objective at ``lam``: ``min(apex, ellipsoid)`` bound for the hull, else the latter."""
    g = 0.0
    a = 0.0
    w0 = 0.0
    w1 = 0.0
    w2 = 0.0
    for i in range(A.shape[0]):
        g += lam[i] * (A[i, 0] * c[0] + A[i, 1] * c[1] + A[i, 2] * c[2] - b[i])
        a += lam[i] * (A[i, 0] * o[0] + A[i, 1] * o[1] + A[i, 2] * o[2] - b[i])
        w0 += A[i, 0] * lam[i]
        w1 += A[i, 1] * lam[i]
        w2 += A[i, 2] * lam[i]
    m0 = M[0, 0] * w0 + M[0, 1] * w1 + M[0, 2] * w2
    m1 = M[1, 0] * w0 + M[1, 1] * w1 + M[1, 2] * w2
    m2 = M[2, 0] * w0 + M[2, 1] * w1 + M[2, 2] * w2
    g -= np.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if los:
        return min(a, g)
    return g


@njit(cache=True)
def _refine_multipliers(A, mu, e, G, L, z):
    """Make ``A^T mu = e`` hold (in place) by the smallest *relative* change of ``mu``.

    Off the exact central path ``A^T mu`` only approximates ``e``; the dual bound then lags the
    primal one, to first order where the bound has a kink (the line-of-sight hull). Weighting the
    correction by ``mu^2`` leaves inactive faces (``mu ~ 0``) untouched.
    """
    k = A.shape[0]
    rhs = np.empty(3)
    for p in range(3):
        rhs[p] = e[p]
        for q in range(3):
            G[p, q] = 0.0
    for i in range(k):
        w = mu[i] * mu[i]
        for p in range(3):
            rhs[p] -= A[i, p] * mu[i]
            for q in range(3):
                G[p, q] += w * A[i, p] * A[i, q]
    trace = G[0, 0] + G[1, 1] + G[2, 2]
    for p in range(3):
        G[p, p] += 1e-12 * trace + 1e-300
    _cholesky_solve(G, rhs, L, z)
    for i in range(k):
        step = mu[i] * mu[i] * (A[i, 0] * z[0] + A[i, 1] * z[1] + A[i, 2] * z[2])
        mu[i] = max(mu[i] + step, 0.0)


@njit(cache=True)
def _check_inputs(M, A):
    asym = 0.0
    big = 0.0
    for i in range(3):
        for j in range(3):
            asym = max(asym, abs(M[i, j] - M[j, i]))
            big = max(big, abs(M[i, j]))
    if asym > 1e-9 * big:
        return NOT_SYMMETRIC
    # Positive definite with condition below 1e18 (semi-axis ratio 1e-9): Cholesky pivots.
    L = np.zeros((3, 3))
    for i in range(3):
        for j in range(i + 1):
            acc = M[i, j]
            for m in range(j):
                acc -= L[i, m] * L[j, m]
            if i == j:
                if not acc > 1e-18 * big:
                    return NOT_POSITIVE_DEFINITE
                L[i, i] = np.sqrt(acc)
            else:
                L[i, j] = acc / L[j, j]
    for i in range(A.shape[0]):
        if A[i, 0] * A[i, 0] + A[i, 1] * A[i, 1] + A[i, 2] * A[i, 2] < 1e-24:
            return ZERO_ROW
    return OK


@njit(cache=True)
def solve_separation(o, c, M, A, b, los, tol):
    """Distance between ``P = {A y <= b}`` and the ellipsoid (``los=False``; ``o`` is ignored) or
    ``conv({o} ∪ E)`` (``los=True``).

    Parameters
    ----------
    o, c : (3,) float
    M : (3, 3) float, symmetric positive definite (checked)
    A : (k, 3) float, non-zero rows (checked)
    b : (k,) float
    los : bool
    tol : float
        Stop once upper and lower bound agree within ``tol`` (m).

    Returns
    -------
    status : int
        ``OK`` or one of the error codes above.
    lower : float
        Dual lower bound at ``lam``.
    upper : float
        ``|x - y|`` for explicit points ``x`` of the set and ``y`` of ``P`` (inf if none found).
    lam : (k,) float
        ``lam >= 0`` with ``|A^T lam| = 1`` (zeros if ``A^T mu`` vanished).
    newton : int
        Newton steps taken.
    """
    k = A.shape[0]
    lam_best = np.zeros(k)
    status = _check_inputs(M, A)
    if status != OK:
        return status, -np.inf, np.inf, lam_best, 0
    if not los:
        o = c
    d = c - o
    bmax = 0.0
    for i in range(k):
        bmax = max(bmax, abs(b[i]))

    # f = 1/2 |e|^2 with e = J v + o, J = [M | d | -I]: its Hessian J^T J is constant.
    J = np.zeros((3, 7))
    # element by element: array slice assignments make numba compile its shape-mismatch message
    # formatting (seconds of first-run compilation)
    for j in range(3):
        for q in range(3):
            J[j, q] = M[j, q]
        J[j, 3] = d[j]
        J[j, 4 + j] = -1.0
    JTJ = J.T @ J
    if not los:
        JTJ[3, :] = 0.0
        JTJ[:, 3] = 0.0

    v = np.zeros(7)
    v[3] = 0.5 if los else 1.0
    for j in range(3):
        v[4 + j] = o[j] + v[3] * d[j]
    s = np.empty(k)
    viol = 0.0
    for i in range(k):
        viol = max(viol, A[i, 0] * v[4] + A[i, 1] * v[5] + A[i, 2] * v[6] - b[i])
    length = max(viol, 1e-3)
    for i in range(k):
        s[i] = max(b[i] - (A[i, 0] * v[4] + A[i, 1] * v[5] + A[i, 2] * v[6]), length)
    nu = k + (3.0 if los else 1.0)
    t = nu / (length * length)
    scale = 1.0 + bmax
    for j in range(3):
        scale += abs(c[j]) + abs(o[j])
    gap_floor = _GAP_FLOOR * scale * scale

    H = np.zeros((7, 7))
    L = np.zeros((7, 7))
    g = np.zeros(7)
    dv = np.zeros(7)
    v_try = np.zeros(7)
    e = np.zeros(3)
    r = np.zeros(k)
    ds = np.zeros(k)
    s_try = np.zeros(k)
    mu = np.zeros(k)
    G3 = np.zeros((3, 3))
    L3 = np.zeros((3, 3))
    z3 = np.zeros(3)
    lower = -np.inf
    upper = np.inf
    residual = np.inf
    newton = 0
    while newton < _MAX_NEWTON:
        # The barrier objective at v for this t, once known: the value the accepted step's line
        # search computed at the very point v now holds (bit for bit what a recomputation gives).
        phi_known = False
        phi_cur = 0.0
        for _centering in range(_MAX_CENTERING):
            newton += 1
            # Gradient and Hessian of t f + psi (theta frozen at 1 for the plain ellipsoid).
            _residual(o, d, M, v, e)
            for p in range(7):
                g[p] = t * (J[0, p] * e[0] + J[1, p] * e[1] + J[2, p] * e[2])
                for q in range(7):
                    H[p, q] = t * JTJ[p, q]
            th = v[3]
            uu = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
            if los:
                w = th * th - uu
                grad_w = (-2.0 * v[0], -2.0 * v[1], -2.0 * v[2], 2.0 * th)
                for i in range(3):
                    g[i] += 2.0 * v[i] / w
                    H[i, i] += 2.0 / w
                g[3] += -2.0 * th / w + 1.0 / (1.0 - th)
                H[3, 3] += -2.0 / w + 1.0 / ((1.0 - th) * (1.0 - th))
                for i in range(4):
                    for j in range(4):
                        H[i, j] += grad_w[i] * grad_w[j] / (w * w)
            else:
                w = 1.0 - uu
                for i in range(3):
                    g[i] += 2.0 * v[i] / w
                    H[i, i] += 2.0 / w
                    for j in range(3):
                        H[i, j] += 4.0 * v[i] * v[j] / (w * w)
                g[3] = 0.0
                H[3, 3] = 1.0
            # Slack barrier -sum log s with s eliminated through s + ds = b - A (y + dy).
            residual = 0.0
            for i in range(k):
                r[i] = b[i] - s[i] - (A[i, 0] * v[4] + A[i, 1] * v[5] + A[i, 2] * v[6])
                residual = max(residual, abs(r[i]))
                inv_s = 1.0 / s[i]
                dg = inv_s - inv_s * inv_s * r[i]
                dii = inv_s * inv_s
                for p in range(3):
                    g[4 + p] += A[i, p] * dg
                    for q in range(3):
                        H[4 + p, 4 + q] += dii * A[i, p] * A[i, q]
            for p in range(7):
                g[p] = -g[p]
            _cholesky_solve(H, g, L, dv)
            decrement = 0.0
            for p in range(7):
                decrement += g[p] * dv[p]
            # Fraction-to-boundary step on s, then backtracking into the cone / theta domain and,
            # once feasible, on the barrier objective (Armijo).
            alpha = 1.0
            for i in range(k):
                ds[i] = r[i] - (A[i, 0] * dv[4] + A[i, 1] * dv[5] + A[i, 2] * dv[6])
                if ds[i] < 0.0:
                    alpha = min(alpha, -0.99 * s[i] / ds[i])
            feasible = residual <= 1e-12 * (1.0 + bmax)
            phi0 = 0.0  # only the feasible (Armijo) search reads it
            if feasible:
                phi0 = phi_cur if phi_known else _barrier_value(v, s, o, d, M, t, los, e)
            accepted = False
            for _ls in range(60):
                for p in range(7):
                    v_try[p] = v[p] + alpha * dv[p]
                for i in range(k):
                    s_try[i] = s[i] + alpha * ds[i]
                phi1 = _barrier_value(v_try, s_try, o, d, M, t, los, e)
                if phi1 < np.inf and (not feasible or phi1 <= phi0 - 0.25 * alpha * decrement):
                    accepted = True
                    break
                alpha *= 0.5
            if not accepted:
                break
            phi_cur = phi1
            phi_known = True
            for p in range(7):
                v[p] = v_try[p]
            for i in range(k):
                s[i] = s_try[i]
            if feasible and 0.5 * decrement < _CENTERING_TOL:
                break
        # Bounds at this point of the central path.
        _residual(o, d, M, v, e)
        residual = 0.0
        for i in range(k):
            r[i] = b[i] - s[i] - (A[i, 0] * v[4] + A[i, 1] * v[5] + A[i, 2] * v[6])
            residual = max(residual, abs(r[i]))
            mu[i] = 1.0 / (t * s[i])
        if residual <= 1e-9 * (1.0 + bmax):
            upper = min(upper, np.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]))
        _refine_multipliers(A, mu, e, G3, L3, z3)
        a0 = 0.0
        a1 = 0.0
        a2 = 0.0
        for i in range(k):
            a0 += A[i, 0] * mu[i]
            a1 += A[i, 1] * mu[i]
            a2 += A[i, 2] * mu[i]
        n_atm = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        if n_atm > 0.0 and np.isfinite(n_atm):
            for i in range(k):
                mu[i] /= n_atm
            bound = _dual_bound(o, c, M, A, b, mu, los)
            if bound > lower:
                lower = bound
                for i in range(k):
                    lam_best[i] = mu[i]
        if upper - max(lower, 0.0) <= tol or nu / t < gap_floor:
            break
        t *= _T_GROWTH
    if residual > 1e-6 * (1.0 + bmax):
        return EMPTY_POLYTOPE, lower, upper, lam_best, newton
    return OK, lower, upper, lam_best, newton


_BOX_A = np.array(
    [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, 1.0],
        [-1.0, 0.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, -1.0],
    ]
)


@njit(cache=True, inline="always")
def _box_rows(lo, hi, c, o, rel_tol, b):
    """The box lo <= y <= hi as the offsets ``b`` (6,) of the faces :data:`_BOX_A` (written in
    place), and the solve's tolerance for it against a set about ``c`` seen from ``o``:
    ``rel_tol`` times the scene's size (at least 1 m)."""
    scale = 1.0
    for j in range(3):
        b[j] = hi[j]
        b[3 + j] = -lo[j]
        scale = max(scale, abs(b[j]), abs(b[3 + j]), abs(c[j]), abs(o[j]))
    return rel_tol * scale


@njit(cache=True)
def box_distances(O, C, M, lo, hi, los, rel_tol):
    """Distances of ``n`` (ellipsoid or line-of-sight hull, box) pairs in one call.

    ``O, C`` (n, 3), ``M`` (n, 3, 3), ``lo, hi`` (n, 3), ``los`` (n,) bool. Returns (status (n,),
    distance (n,), lam (n, 6)): the certified lower bound of :func:`solve_separation`, 0 where the
    sets touch within its tolerance (the same numbers as ``polytope.los_hull_distance`` /
    ``ellipsoid_polytope_distance`` pair by pair, without their per-call Python overhead), and the
    dual that certifies it (faces ``+x, +y, +z, -x, -y, -z``; zeros where the sets touch).
    """
    n = C.shape[0]
    status = np.zeros(n, np.int64)
    dist = np.zeros(n)
    lams = np.zeros((n, 6))
    b = np.empty(6)
    for i in range(n):
        tol = _box_rows(lo[i], hi[i], C[i], O[i], rel_tol, b)
        st, lower, upper, lam, _ = solve_separation(O[i], C[i], M[i], _BOX_A, b, los[i], tol)
        status[i] = st
        if st == OK and upper > tol and lower > 0.0:
            dist[i] = lower
            for j in range(6):  # not lams[i] = lam: see solve_separation's J
                lams[i, j] = lam[j]
    return status, dist, lams


@njit(cache=True, inline="always")
def _box_support(n0, n1, n2, lo, hi):
    """max of n . y over the box lo <= y <= hi (rows of (m, 3) arrays)."""
    return max(n0 * lo[0], n0 * hi[0]) + max(n1 * lo[1], n1 * hi[1]) + max(n2 * lo[2], n2 * hi[2])


@njit(cache=True)
def _plane_apart(o, c, M, lo, hi, p, los, tol):
    """Whether the plane through the box's point nearest ``p``, normal to the way from it to
    ``p``, separates the box from E = {c + M z : |z| <= 1} (and from ``o`` where ``los``) by more
    than ``tol``: a sufficient test (the box lies in ``n . y <= h_B(n)``; E's least ``n . y`` is
    ``n . c - |M^T n|``)."""
    n0 = p[0] - min(max(p[0], lo[0]), hi[0])
    n1 = p[1] - min(max(p[1], lo[1]), hi[1])
    n2 = p[2] - min(max(p[2], lo[2]), hi[2])
    norm = np.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
    if norm <= 0.0:
        return False  # p in the box
    n0, n1, n2 = n0 / norm, n1 / norm, n2 / norm
    m0 = M[0, 0] * n0 + M[1, 0] * n1 + M[2, 0] * n2
    m1 = M[0, 1] * n0 + M[1, 1] * n1 + M[2, 1] * n2
    m2 = M[0, 2] * n0 + M[1, 2] * n1 + M[2, 2] * n2
    least = n0 * c[0] + n1 * c[1] + n2 * c[2] - np.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if los:
        least = min(least, n0 * o[0] + n1 * o[1] + n2 * o[2])
    return least > _box_support(n0, n1, n2, lo, hi) + tol


@njit(cache=True)
def boxes_apart(o, c, M, lo, hi, near, los, rel_tol):
    """Whether every box ``near`` (indices into ``lo, hi`` (n, 3)) lies at a positive distance from
    E = {c + M z : |z| <= 1} (``los`` False; ``o`` ignored) or from conv({o} ∪ E): the answer of
    :func:`box_distances` (> 0 for every pair), stopping at the first box that touches. A box that
    a plane through its point nearest ``c`` (for the hull also nearest ``o`` or the midpoint of o
    and c) shows apart by more than the solve's tolerance needs no solve. Returns (status, apart):
    status ``OK`` or the first solve's error code."""
    b = np.empty(6)
    mid = 0.5 * (o + c)
    for i in near:
        tol = _box_rows(lo[i], hi[i], c, o, rel_tol, b)
        if _plane_apart(o, c, M, lo[i], hi[i], c, los, tol):
            continue
        if los and (
            _plane_apart(o, c, M, lo[i], hi[i], o, los, tol)
            or _plane_apart(o, c, M, lo[i], hi[i], mid, los, tol)
        ):
            continue
        st, lower, upper, lam, _ = solve_separation(o, c, M, _BOX_A, b, los, tol)
        if st != OK:
            return st, False
        if not (upper > tol and lower > 0.0):
            return OK, False
    return OK, True
