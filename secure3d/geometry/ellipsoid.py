"""Ellipsoids ``E = {c + M z : |z| <= 1}`` with ``M`` symmetric positive definite.

This is the paper's eq. ReactEllipse, ``R sqrt(Q) R^T`` (plus the offset ``a``, folded into ``c``).
Containment in a convex polytope is exact through the support function (DESIGN.md section 4,
"Ellipsoids"): ``E ⊂ {y : A y <= b}`` iff ``A_i c + |M A_i| <= b_i`` for every row.

Kernels marked "numpy or CasADi" share one body through :mod:`.backend`. In numpy they broadcast
over a leading batch of ellipsoids: ``center (N, 3)``, ``shape (N, 3, 3)``.
"""

from __future__ import annotations

import numpy as np

from secure3d.errors import GeometryError
from secure3d.geometry import backend as B
from secure3d.geometry.backend import ArrayOrSym
from secure3d.validation import is_int_in

#: Relative asymmetry ``max |M - M^T| / max |M|`` accepted (and removed) by check_ellipsoid.
SYMMETRY_TOL = 1e-9
#: Smallest accepted ratio of the smallest to the largest semi-axis. Below it the ellipsoid is
#: numerically flat and ``M^{-1}`` (used by contains_points) is meaningless.
MIN_AXIS_RATIO = 1e-9
#: Slack on ``|M^{-1}(p - c)| <= 1`` in contains_points, so surface points count as inside.
CONTAINS_TOL = 1e-9


def check_ellipsoid(center: object, shape: object) -> tuple[np.ndarray, np.ndarray]:
    """Validate an ellipsoid (or a batch) and return clean float arrays.

    Parameters
    ----------
    center : (..., 3) array-like
    shape : (..., 3, 3) array-like, symmetric positive definite (symmetrised on return).

    Returns
    -------
    c : (..., 3) float
    M : (..., 3, 3) float, exactly symmetric.

    Raises
    ------
    GeometryError
        Wrong shapes, non-finite entries, asymmetric or not positive definite ``shape``.
    """
    try:
        c = np.asarray(center, dtype=float)
        M = np.asarray(shape, dtype=float)
    except (TypeError, ValueError):
        raise GeometryError("ellipsoid: center and shape must be numeric arrays") from None
    if c.shape[-1:] != (3,):
        raise GeometryError(f"ellipsoid center: expected shape (..., 3), got {c.shape}")
    if M.shape[-2:] != (3, 3):
        raise GeometryError(f"ellipsoid shape: expected shape (..., 3, 3), got {M.shape}")
    if M.shape[:-2] != c.shape[:-1]:
        raise GeometryError(
            f"ellipsoid: batch shapes differ, center {c.shape} vs shape matrix {M.shape}"
        )
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(M))):
        raise GeometryError("ellipsoid: center and shape must be finite")
    Mt = np.swapaxes(M, -1, -2)
    scale = np.abs(M).max(initial=0.0)
    asym = np.abs(M - Mt).max(initial=0.0)
    if asym > SYMMETRY_TOL * max(scale, 1e-300):
        raise GeometryError(f"ellipsoid shape: not symmetric, max |M - M^T| = {asym:.3g}")
    M = 0.5 * (M + Mt)
    if M.size:
        eig = np.linalg.eigvalsh(M)
        lo, hi = eig[..., 0], eig[..., -1]
        bad = ~(lo > MIN_AXIS_RATIO * hi) | ~(hi > 0)
        if np.any(bad):
            worst = float(np.min(lo))
            raise GeometryError(
                f"ellipsoid shape: not positive definite (smallest eigenvalue {worst:.3g})"
            )
    return c, M


def _inputs(center, shape, *others):
    """Dispatch helper: validated numpy arrays, or CasADi objects, plus the backend flag."""
    sym = B.is_symbolic(center, shape, *others)
    if sym:
        return sym, B.vector(center, True), B.matrix(shape, True)
    c, M = check_ellipsoid(center, shape)
    return sym, c, M


def _rows(A: object, sym: bool, what: str):
    if sym:
        return B.matrix(A, True)
    A = np.asarray(A, dtype=float)
    if A.ndim == 1:
        A = A[None, :]
    if A.shape[-1] != 3:
        raise GeometryError(f"{what}: expected shape (..., k, 3), got {A.shape}")
    if not np.all(np.isfinite(A)):
        raise GeometryError(f"{what}: entries must be finite")
    return A


def support(center: ArrayOrSym, shape: ArrayOrSym, normals: ArrayOrSym) -> ArrayOrSym:
    """Support function ``h(n) = n.c + |M n|`` in each direction, numpy or CasADi.

    Parameters
    ----------
    center : (3,) or (N, 3) float, or CasADi (3, 1)
    shape : (3, 3) or (N, 3, 3) float, or CasADi 3x3
    normals : (k, 3) float or CasADi (k, 3); need not be unit (``h`` is positively homogeneous).
        numpy also accepts ``(N, k, 3)``: a separate set of directions per ellipsoid.

    Returns
    -------
    (k,) or (N, k) float, or CasADi (k, 1).
    """
    sym, c, M = _inputs(center, shape, normals)
    N = _rows(normals, sym, "normals")
    return B.matvec(N, c) + B.row_norms(B.matmul(N, B.transpose(M)))


def halfspace_margins(
    center: ArrayOrSym, shape: ArrayOrSym, A: ArrayOrSym, b: ArrayOrSym
) -> ArrayOrSym:
    """Slack of the ellipsoid in every half-space ``A_i y <= b_i``: ``b - h(A_i)``, numpy or CasADi.

    With unit rows of ``A`` each margin is a metric distance: positive means the whole ellipsoid
    is inside that half-space with this much room (DESIGN.md section 4, "Camera frustum"). This is
    the constraint vector the planner imposes ``>= 0`` (eq. SensorModel made exact).

    Parameters
    ----------
    center : (3,) or (N, 3) float, or CasADi (3, 1)
    shape : (3, 3) or (N, 3, 3) float, or CasADi 3x3
    A : (k, 3) float or CasADi; numpy also ``(N, k, 3)`` (one polytope per ellipsoid).
    b : (k,) float or CasADi (k, 1); numpy also ``(N, k)``.

    Returns
    -------
    (k,) or (N, k) float, or CasADi (k, 1).
    """
    sym = B.is_symbolic(center, shape, A, b)
    h = support(center, shape, A)
    if sym:
        return B.vector(b, True) - B.vector(h, True)
    b = np.asarray(b, dtype=float)
    if b.shape[-1:] != h.shape[-1:] or not np.all(np.isfinite(b)):
        raise GeometryError(f"b: expected {h.shape[-1]} finite offsets, got shape {b.shape}")
    return b - h


def containment_margin(
    center: ArrayOrSym, shape: ArrayOrSym, A: ArrayOrSym, b: ArrayOrSym
) -> ArrayOrSym:
    """Smallest half-space margin: ``E ⊂ {A y <= b}`` iff the result is ``>= 0``.

    numpy returns a float (or ``(N,)`` for a batch); CasADi a (non-smooth) scalar ``mmin``, meant
    for reporting. Constrain :func:`halfspace_margins` entry-wise instead in an NLP.
    """
    return B.vmin(halfspace_margins(center, shape, A, b))


def contains_points(center: object, shape: object, points: object) -> np.ndarray:
    """Which points lie in the ellipsoid: ``|M^{-1}(p - c)| <= 1`` (+ ``CONTAINS_TOL``), numpy.

    Parameters
    ----------
    center : (3,) float
    shape : (3, 3) float
    points : (n, 3) float

    Returns
    -------
    (n,) bool
    """
    c, M = check_ellipsoid(center, shape)
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    z = np.linalg.solve(M, (p - c).T).T
    return np.linalg.norm(z, axis=-1) <= 1.0 + CONTAINS_TOL


def surface_points(center: object, shape: object, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` surface points ``c + M z`` with ``z`` uniform on the unit sphere, numpy.

    The directions are uniform; the points are not uniform by area on a strongly elongated
    ellipsoid (they crowd at the ends of the long axes).

    Returns
    -------
    (n, 3) float
    """
    c, M = check_ellipsoid(center, shape)
    if not is_int_in(n, 0, numpy=True):
        raise GeometryError(f"surface_points: n must be a non-negative integer, got {n!r}")
    z = rng.standard_normal((int(n), 3))
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    return c + z @ M.T


def volume(shape: object) -> float | np.ndarray:
    """Volume ``4/3 pi det(M)`` (m^3) of ``{c + M z : |z| <= 1}``; ``(N,)`` for a batch."""
    M = np.asarray(shape, dtype=float)
    _, M = check_ellipsoid(np.zeros(M.shape[:-1]), M)
    return 4.0 / 3.0 * np.pi * np.linalg.det(M)


def ellipsoid_from_axes(
    center: object, axes: object, semi_axes: object
) -> tuple[np.ndarray, np.ndarray]:
    """``(c, M)`` of the ellipsoid with principal directions ``axes`` (columns) and semi-axes.

    Parameters
    ----------
    center : (3,) float
    axes : (3, 3) float, orthonormal columns (a reflection is fine: only ``U S U^T`` matters).
    semi_axes : (3,) float, > 0 (m)

    Returns
    -------
    c : (3,) float
    M : (3, 3) float, ``axes @ diag(semi_axes) @ axes.T``.
    """
    U = np.asarray(axes, dtype=float)
    s = np.asarray(semi_axes, dtype=float)
    if U.shape != (3, 3) or not np.all(np.isfinite(U)):
        raise GeometryError(f"axes: expected a finite (3, 3) array, got shape {U.shape}")
    err = np.abs(U.T @ U - np.eye(3)).max()
    if err > 1e-6:
        raise GeometryError(f"axes: columns not orthonormal, max |U^T U - I| = {err:.3g}")
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise GeometryError(f"semi_axes: expected 3 finite positive numbers, got {s.tolist()}")
    M = (U * s) @ U.T
    return check_ellipsoid(center, 0.5 * (M + M.T))
