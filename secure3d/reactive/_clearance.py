"""Exact ball-in-ellipsoid tests, compiled with numba.

For an ellipsoid E = {c + M z : |z| <= 1} and a point y, the *clearance* is the radius of the
largest ball centred at y that fits in E (y inside), or minus the distance from y to E (y outside).
A body ball B(y, r) lies in E exactly when ``clearance >= r``.

Inside: in the eigenbasis of M (semi-axes a_i, q_i = 1/a_i^2), B(y, r) is in E iff (S-lemma, exact
because B has an interior point) some lambda >= q_max makes
``1 - |z|^2_Q - lambda (r^2 - |z - y|^2) >= 0`` for all z. Minimising over z gives
``r^2 <= psi(lambda) = (1 - y'Qy - sum_i w_i / (lambda - q_i)) / lambda``, ``w_i = y_i^2 q_i^2``,
so ``clearance^2 = sup psi``. psi is unimodal (its derivative's numerator is decreasing), so the
supremum is found by bisection on the sign of the derivative, in log(lambda - q_max).

Outside: the nearest point of E is ``z_i = y_i / (1 + t q_i)`` with t > 0 solving
``sum_i q_i y_i^2 / (1 + t q_i)^2 = 1`` (decreasing in t), again by bisection.
"""

from __future__ import annotations

import math

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)

_ITER = 48


@numba.njit(cache=True)
def _clearance_eig(
    y0: float, y1: float, y2: float, a0: float, a1: float, a2: float, enough: float
) -> float:
    q0, q1, q2 = 1.0 / (a0 * a0), 1.0 / (a1 * a1), 1.0 / (a2 * a2)
    val = q0 * y0 * y0 + q1 * y1 * y1 + q2 * y2 * y2
    qmax = max(q0, q1, q2)
    # |Q^(1/2) y| is sqrt(qmax)-Lipschitz, so the boundary is at least this far: skip the exact
    # search when the bound already clears `enough`.
    bound = (1.0 - math.sqrt(val)) / math.sqrt(qmax)
    if bound >= enough:
        return bound
    if val > 1.0:
        qmin = min(q0, q1, q2)
        lo, hi = 0.0, (math.sqrt(val) - 1.0) / qmin
        for _ in range(_ITER):
            t = 0.5 * (lo + hi)
            d0, d1, d2 = 1.0 + t * q0, 1.0 + t * q1, 1.0 + t * q2
            F = q0 * y0 * y0 / (d0 * d0) + q1 * y1 * y1 / (d1 * d1) + q2 * y2 * y2 / (d2 * d2)
            if F > 1.0:
                lo = t
            else:
                hi = t
        t = hi
        e0 = y0 - y0 / (1.0 + t * q0)
        e1 = y1 - y1 / (1.0 + t * q1)
        e2 = y2 - y2 / (1.0 + t * q2)
        return -math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    w0, w1, w2 = y0 * y0 * q0 * q0, y1 * y1 * q1 * q1, y2 * y2 * q2 * q2
    base = 1.0 - val
    lo, hi = math.log(qmax * 1e-15), math.log(qmax * 1e15)
    for _ in range(_ITER):
        mid = 0.5 * (lo + hi)
        lam = qmax + math.exp(mid)
        g0, g1, g2 = lam - q0, lam - q1, lam - q2
        s1 = w0 / g0 + w1 / g1 + w2 / g2
        s2 = w0 / (g0 * g0) + w1 / (g1 * g1) + w2 / (g2 * g2)
        h = lam * s2 - (base - s1)
        if h > 0.0:
            lo = mid
        else:
            hi = mid
    best = 0.0
    for mid in (lo, hi):
        lam = qmax + math.exp(mid)
        psi = (base - w0 / (lam - q0) - w1 / (lam - q1) - w2 / (lam - q2)) / lam
        best = max(best, psi)
    return math.sqrt(best)


@numba.njit(cache=True, parallel=False)
def _clearance_kernel(points, owner, centres, vt, semi, enough):  # pragma: no cover - compiled
    n = points.shape[0]
    out = np.empty(n)
    for i in range(n):
        k = owner[i]
        d0 = points[i, 0] - centres[k, 0]
        d1 = points[i, 1] - centres[k, 1]
        d2 = points[i, 2] - centres[k, 2]
        y0 = vt[k, 0, 0] * d0 + vt[k, 0, 1] * d1 + vt[k, 0, 2] * d2
        y1 = vt[k, 1, 0] * d0 + vt[k, 1, 1] * d1 + vt[k, 1, 2] * d2
        y2 = vt[k, 2, 0] * d0 + vt[k, 2, 1] * d1 + vt[k, 2, 2] * d2
        out[i] = _clearance_eig(y0, y1, y2, semi[k, 0], semi[k, 1], semi[k, 2], enough)
    return out


@numba.njit(cache=True)
def _required_inflation_kernel(local, offsets, semi, radius, tol):  # pragma: no cover - compiled
    m = offsets.shape[0] - 1
    out = np.empty(m)
    for k in range(m):
        a0, a1, a2 = semi[k, 0], semi[k, 1], semi[k, 2]
        start, stop = offsets[k], offsets[k + 1]
        reach = 0.0
        for i in range(start, stop):
            reach = max(reach, math.sqrt(local[i, 0] ** 2 + local[i, 1] ** 2 + local[i, 2] ** 2))
        lo = -min(a0, a1, a2) * (1.0 - 1e-9)
        hi = max(0.0, reach + radius - min(a0, a1, a2))
        while hi - lo > tol:
            eta = 0.5 * (lo + hi)
            ok = True
            b0, b1, b2 = a0 + eta, a1 + eta, a2 + eta
            for i in range(start, stop):
                y0, y1, y2 = local[i, 0], local[i, 1], local[i, 2]
                if _clearance_eig(y0, y1, y2, b0, b1, b2, radius) < radius:
                    ok = False
                    break
            if ok:
                hi = eta
            else:
                lo = eta
        out[k] = hi
    return out


def _eig(shapes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Semi-axes (m, 3) and the transposed eigenvector matrices (m, 3, 3) of SPD shapes."""
    semi, vecs = np.linalg.eigh(0.5 * (shapes + np.swapaxes(shapes, -1, -2)))
    if np.any(~np.isfinite(semi)) or np.any(semi <= 0):
        raise ValueError("ellipsoid shape matrices must be symmetric positive definite")
    return semi, np.ascontiguousarray(np.swapaxes(vecs, -1, -2))


def clearance(
    points: np.ndarray,
    owner: np.ndarray,
    centres: np.ndarray,
    shapes: np.ndarray,
    enough: float = np.inf,
) -> np.ndarray:
    """Signed clearance of points in their ellipsoids (see module docstring).

    Parameters
    ----------
    points : (n, 3) float, world points.
    owner : (n,) int, index of each point's ellipsoid.
    centres : (m, 3) float, ellipsoid centres c.
    shapes : (m, 3, 3) float, symmetric positive definite M (E = {c + M z : |z| <= 1}).
    enough : points whose cheap lower bound ``(1 - |y|_Q) / sqrt(q_max)`` is at least this get
        the bound instead of the exact value (default: exact everywhere).

    Returns
    -------
    (n,) float: the radius of the largest ball around the point inside E, or minus the distance to
    E for points outside (accurate to ~1e-10 relative); a lower bound >= ``enough`` where skipped.
    """
    semi, vt = _eig(np.asarray(shapes, dtype=float))
    return _clearance_kernel(
        np.ascontiguousarray(points, dtype=float),
        np.ascontiguousarray(owner, dtype=np.int64),
        np.ascontiguousarray(centres, dtype=float),
        vt,
        np.ascontiguousarray(semi),
        float(enough),
    )


def required_inflation(
    points: np.ndarray,
    offsets: np.ndarray,
    centres: np.ndarray,
    shapes: np.ndarray,
    radius: float,
    tol: float = 1e-5,
) -> np.ndarray:
    """Smallest eta with every ball B(p, radius) of group k inside E(c_k, M_k + eta I).

    Parameters
    ----------
    points : (n, 3) float, grouped by ellipsoid: group k is ``points[offsets[k]:offsets[k+1]]``.
    offsets : (m + 1,) int.
    centres, shapes : (m, 3), (m, 3, 3) float.
    radius : body radius (m).
    tol : bisection tolerance (m); the returned eta is feasible (upper end of the bracket).

    Returns
    -------
    (m,) float; negative when the ellipsoid could shrink.
    """
    semi, vt = _eig(np.asarray(shapes, dtype=float))
    offsets = np.asarray(offsets, dtype=np.int64)
    owner = np.repeat(np.arange(len(centres)), np.diff(offsets))
    local = np.einsum("nij,nj->ni", vt[owner], np.asarray(points, dtype=float) - centres[owner])
    return _required_inflation_kernel(
        np.ascontiguousarray(local), offsets, semi, float(radius), float(tol)
    )
