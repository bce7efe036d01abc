"""Convex polytopes ``P = {y : A y <= b}``: boxes, convex hulls, distances and separation.

The planner keeps reactive-set ellipsoids (and their line-of-sight hulls) away from known
obstacles through a dual certificate (DESIGN.md section 4, "Known obstacles" and "Occlusion"):

    dist(E, P) >= m   <=   exists lam >= 0, |A^T lam| <= 1,  lam.(A c - b) - |M A^T lam| >= m,

and for the hull ``H = conv({o} ∪ E)`` the same ``lam`` must also give ``lam.(A o - b) >= m``.
By LP duality the best ``lam`` attains the exact distance. :func:`dual_separation_margin` and
:func:`los_hull_margins` are those constraint functions (numpy or CasADi);
:func:`ellipsoid_polytope_distance` and :func:`los_hull_distance` compute the exact distance and an
optimal ``lam`` (numpy) to initialise the NLP's multiplier variables and to check plans.
"""

from __future__ import annotations

import functools

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from secure3d.errors import GeometryError
from secure3d.geometry import backend as B
from secure3d.geometry.backend import ArrayOrSym
from secure3d.geometry.ellipsoid import check_ellipsoid

#: Two hull facets whose unit normals differ by less than this (max-norm) are one face.
NORMAL_MERGE_TOL = 1e-9
#: Target accuracy of the distance solvers relative to the scene size (m per m).
DISTANCE_REL_TOL = 1e-9

_BOX_NORMALS = np.vstack([np.eye(3), -np.eye(3)])
_BOX_NORMALS.setflags(write=False)


# --------------------------------------------------------------------------------------------
# Construction and validation
# --------------------------------------------------------------------------------------------


def _boxes(lo: object, hi: object) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    if lo.shape[-1:] != (3,) or lo.shape != hi.shape:
        raise GeometryError(
            f"box: lo and hi must have the same shape (..., 3), got {lo.shape}, {hi.shape}"
        )
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise GeometryError("box: lo and hi must be finite")
    if np.any(lo > hi):
        i = np.argwhere(np.any(lo > hi, axis=-1))[0]
        raise GeometryError(
            f"box: lo must not exceed hi, got lo={lo[tuple(i)].tolist()} hi={hi[tuple(i)].tolist()}"
        )
    return lo, hi


def box_halfspaces(lo: object, hi: object) -> tuple[np.ndarray, np.ndarray]:
    """Faces of the axis-aligned box ``lo <= y <= hi``.

    Returns
    -------
    A : (6, 3) float, unit rows ``+x, +y, +z, -x, -y, -z``.
    b : (6,) float, ``(hi, -lo)``.
    """
    lo, hi = _boxes(lo, hi)
    if lo.shape != (3,):
        raise GeometryError(f"box_halfspaces: expected lo, hi of shape (3,), got {lo.shape}")
    return _BOX_NORMALS.copy(), np.concatenate([hi, -lo])


def boxes_halfspaces(lo: object, hi: object) -> tuple[np.ndarray, np.ndarray]:
    """Faces of ``n`` boxes at once.

    Parameters
    ----------
    lo, hi : (n, 3) float

    Returns
    -------
    A : (n, 6, 3) float
    b : (n, 6) float
    """
    lo, hi = _boxes(lo, hi)
    lo, hi = lo.reshape(-1, 3), hi.reshape(-1, 3)
    A = np.broadcast_to(_BOX_NORMALS, (lo.shape[0], 6, 3)).copy()
    return A, np.concatenate([hi, -lo], axis=-1)


def convex_hull_halfspaces(vertices: object) -> tuple[np.ndarray, np.ndarray]:
    """Faces of the convex hull of points, coplanar facets merged.

    Parameters
    ----------
    vertices : (n, 3) float, n >= 4, not all in one plane.

    Returns
    -------
    A : (k, 3) float, unit outward normals, one per distinct face plane.
    b : (k,) float
    """
    V = np.asarray(vertices, dtype=float)
    if V.ndim != 2 or V.shape[1] != 3 or V.shape[0] < 4:
        raise GeometryError(f"convex hull: expected (n >= 4, 3) vertices, got shape {V.shape}")
    if not np.all(np.isfinite(V)):
        raise GeometryError("convex hull: vertices must be finite")
    extent = float(np.max(V.max(axis=0) - V.min(axis=0)))
    try:
        hull = ConvexHull(V)
    except QhullError as exc:
        raise GeometryError(f"convex hull: degenerate (flat or repeated) vertices: {exc}") from None
    # A volume this small relative to the extent means the points are (numerically) coplanar.
    if not hull.volume > 1e-12 * extent**3:
        raise GeometryError(f"convex hull: vertices are flat (volume {hull.volume:.3g})")
    N = hull.equations[:, :3]
    off = -hull.equations[:, 3]
    scale = np.linalg.norm(N, axis=1)
    N, off = N / scale[:, None], off / scale
    same = np.abs(N[:, None, :] - N[None, :, :]).max(axis=-1) < NORMAL_MERGE_TOL
    group = np.argmax(same, axis=1)  # first facet with the same normal
    keep, inverse = np.unique(group, return_inverse=True)
    b = np.full(keep.shape, -np.inf)
    np.maximum.at(b, inverse, off)
    return N[keep], b


# --------------------------------------------------------------------------------------------
# Point / segment queries against boxes
# --------------------------------------------------------------------------------------------


def box_signed_distance(points: object, lo: object, hi: object) -> np.ndarray:
    """Exact signed Euclidean distance from points to boxes (negative inside).

    Parameters
    ----------
    points : (n, 3) float
    lo, hi : (m, 3) float

    Returns
    -------
    (n, m) float
    """
    p = np.asarray(points, dtype=float).reshape(-1, 3)
    lo, hi = _boxes(lo, hi)
    lo, hi = lo.reshape(-1, 3), hi.reshape(-1, 3)
    q = np.maximum(lo[None] - p[:, None], p[:, None] - hi[None])  # (n, m, 3) per-axis excess
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
    inside = np.minimum(q.max(axis=-1), 0.0)
    return outside + inside


def _points_and_boxes(
    points: object, lo: object, hi: object
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (n, 3) and box corners (m, 3), checked and contiguous, for the compiled kernels."""
    lo, hi = _boxes(lo, hi)
    return (
        np.ascontiguousarray(np.asarray(points, dtype=float).reshape(-1, 3)),
        np.ascontiguousarray(lo.reshape(-1, 3)),
        np.ascontiguousarray(hi.reshape(-1, 3)),
    )


def min_box_distance(points: object, lo: object, hi: object) -> np.ndarray:
    """Smallest signed distance from each point to any box (``+inf`` without boxes).

    Returns
    -------
    (n,) float
    """
    return _kernels().min_signed_distance(*_points_and_boxes(points, lo, hi))


def inside_any_box(points: object, lo: object, hi: object) -> np.ndarray:
    """Whether each point lies strictly inside some box: ``min_box_distance(...) < 0``, with an
    early exit at the first such box.

    Returns
    -------
    (n,) bool
    """
    return _kernels().inside_any(*_points_and_boxes(points, lo, hi))


def _segments_and_boxes(
    p0: object, p1: object, lo: object, hi: object, what: str = "segments"
) -> tuple:
    """Validated contiguous (n, 3) segment ends and (m, 3) box corners for the compiled kernels."""
    p0 = np.asarray(p0, dtype=float).reshape(-1, 3)
    p1 = np.asarray(p1, dtype=float).reshape(-1, 3)
    if p0.shape != p1.shape:
        raise GeometryError(f"{what}: the two end arrays differ in shape, {p0.shape} vs {p1.shape}")
    lo, hi = _boxes(lo, hi)
    return tuple(np.ascontiguousarray(a.reshape(-1, 3)) for a in (p0, p1, lo, hi))


def segment_box_intersects(p0: object, p1: object, lo: object, hi: object) -> np.ndarray:
    """Whether each segment ``[p0_i, p1_i]`` touches each closed box (slab test).

    Parameters
    ----------
    p0, p1 : (n, 3) float
    lo, hi : (m, 3) float

    Returns
    -------
    (n, m) bool
    """
    return _kernels().segment_box_matrix(*_segments_and_boxes(p0, p1, lo, hi))


def segments_blocked(p0: object, p1: object, lo: object, hi: object) -> np.ndarray:
    """Whether each segment ``[p0_i, p1_i]`` touches any of the boxes: ``segment_box_intersects(...)
    .any(axis=1)`` with an early exit per segment.

    Returns
    -------
    (n,) bool
    """
    return _kernels().segment_box_any(*_segments_and_boxes(p0, p1, lo, hi))


def polyline_distance(points: object, path: object) -> np.ndarray:
    """Euclidean distance from each point to the polyline through ``path`` (its segments
    ``path[j] -> path[j + 1]``; one vertex is a point). A ball of radius r about ``points[i]`` lies
    in the union of the balls of radius r about the polyline iff this distance is 0.

    Parameters
    ----------
    points : (n, 3) float
    path : (m, 3) float, m >= 1

    Returns
    -------
    (n,) float
    """
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or not np.all(np.isfinite(p)):
        raise GeometryError(f"polyline_distance: points must be (n, 3) finite, got {p.shape}")
    q = np.asarray(path, dtype=float)
    if q.ndim != 2 or q.shape[1] != 3 or len(q) == 0 or not np.all(np.isfinite(q)):
        raise GeometryError(f"polyline_distance: path must be (m >= 1, 3) finite, got {q.shape}")
    if len(q) == 1:
        return np.linalg.norm(p - q[0], axis=1)
    return _kernels().polyline_distances(np.ascontiguousarray(p), np.ascontiguousarray(q))


def cones_blocked(
    apex: object, centre: object, lo: object, hi: object, radius: float
) -> np.ndarray:
    """Whether some box meets each sight cone conv({apex_i} ∪ B(centre_i, radius)): the lines of
    sight from a camera at ``apex`` to every point of a ball (exact, via the convex gap
    dist(apex + t (centre - apex), box) - t radius over t in [0, 1]).

    Returns
    -------
    (n,) bool
    """
    if not np.isfinite(radius) or radius < 0:
        raise GeometryError(f"radius: must be finite and >= 0, got {radius!r}")
    return _kernels().cone_box_blocked_any(
        *_segments_and_boxes(apex, centre, lo, hi, "cones"), float(radius)
    )


@functools.cache
def _kernels():
    from secure3d.geometry import _box_kernels

    return _box_kernels


# --------------------------------------------------------------------------------------------
# Dual separation certificates (numpy or CasADi)
# --------------------------------------------------------------------------------------------


def dual_separation_margin(
    center: ArrayOrSym,
    shape: ArrayOrSym,
    A: ArrayOrSym,
    b: ArrayOrSym,
    lam: ArrayOrSym,
    eps: float = 1e-6,
) -> ArrayOrSym:
    """Dual lower bound on ``dist(E, P)``: ``lam.(A c - b) - smooth_norm(M A^T lam, eps)``.

    For any ``lam >= 0`` with ``|A^T lam| <= 1`` the result is ``<= dist(E, P)`` (weak duality,
    DESIGN.md section 4, "Known obstacles"); the smooth norm (``|x| <= sqrt(|x|^2 + eps^2)``) keeps
    the gradient defined at ``A^T lam = 0`` and only lowers the bound, by at most ``eps``. The
    planner imposes ``>= clearance`` with ``lam`` as extra decision variables.

    Parameters
    ----------
    center : (3,) or (N, 3) float, or CasADi (3, 1)
    shape : (3, 3) or (N, 3, 3) float, or CasADi 3x3
    A : (k, 3) float or CasADi
    b : (k,) float or CasADi (k, 1)
    lam : (k,) or (N, k) float, or CasADi (k, 1)
    eps : float
        Smoothing of the norm (m).

    Returns
    -------
    float (``(N,)`` for a batch), or CasADi scalar.
    """
    sym = B.is_symbolic(center, shape, A, b, lam)
    if sym:
        c, M = B.vector(center, True), B.matrix(shape, True)
    else:
        c, M = check_ellipsoid(center, shape)
    A, b, lam = B.matrix(A, sym), B.vector(b, sym), B.vector(lam, sym)
    w = B.matvec(B.transpose(A), lam)
    return B.dot(lam, B.matvec(A, c) - b) - B.smooth_norm(B.matvec(M, w), eps)


def los_hull_margins(
    origin: ArrayOrSym,
    center: ArrayOrSym,
    shape: ArrayOrSym,
    A: ArrayOrSym,
    b: ArrayOrSym,
    lam: ArrayOrSym,
    eps: float = 1e-6,
) -> tuple[ArrayOrSym, ArrayOrSym]:
    """The two dual bounds certifying that ``H = conv({o} ∪ E)`` misses ``P`` (numpy or CasADi).

    Returns ``(lam.(A o - b), dual_separation_margin(c, M, A, b, lam, eps))``. If both are
    ``>= m`` for one ``lam >= 0`` with ``|A^T lam| <= 1``, then ``dist(H, P) >= m``: the separating
    plane ``(A^T lam).y = lam.b + m`` clears both the camera ``o`` and ``E`` (DESIGN.md section 4,
    "Occlusion"). Since ``H ⊇ E`` this also replaces the plain obstacle constraint on ``E``.

    Parameters
    ----------
    origin : (3,) float or CasADi (3, 1): the camera centre.
    center, shape, A, b, lam, eps : as in :func:`dual_separation_margin`.

    Returns
    -------
    apex_margin, ellipsoid_margin : float (``(N,)`` for a batch), or CasADi scalars.
    """
    sym = B.is_symbolic(origin, center, shape, A, b, lam)
    o = B.vector(origin, sym)
    A_, b_, lam_ = B.matrix(A, sym), B.vector(b, sym), B.vector(lam, sym)
    apex = B.dot(lam_, B.matvec(A_, o) - b_)
    return apex, dual_separation_margin(center, shape, A_, b_, lam_, eps)


# --------------------------------------------------------------------------------------------
# Exact distances (numpy), for initialisation and checking
# --------------------------------------------------------------------------------------------


@functools.cache
def _kernel():
    # numba is imported on first use only: compiling (or loading the cache) costs seconds.
    from secure3d.geometry import _separation_kernel

    return _separation_kernel


def _vec3(x: object, what: str) -> np.ndarray:
    a = np.ascontiguousarray(x, dtype=float)
    if a.shape != (3,) or not np.isfinite(a.sum()):
        raise GeometryError(f"{what}: expected 3 finite numbers, got {x!r}")
    return a


def _separation(origin, center, shape, A, b, los: bool) -> tuple[float, np.ndarray]:
    # Light checks here; symmetry, definiteness and zero rows are checked inside the kernel
    # (check_ellipsoid's numpy calls would cost more than the solve).
    c = _vec3(center, "center")
    o = c if origin is None else _vec3(origin, "origin")
    M = np.ascontiguousarray(shape, dtype=float)
    A = np.ascontiguousarray(A, dtype=float)
    b = np.ascontiguousarray(b, dtype=float)
    if M.shape != (3, 3) or not np.isfinite(M.sum()):
        raise GeometryError(f"shape: expected a finite (3, 3) matrix, got shape {M.shape}")
    if A.ndim != 2 or A.shape[1] != 3 or A.shape[0] < 1 or b.shape != (A.shape[0],):
        raise GeometryError(f"polytope: expected A (k, 3) and b (k,), got {A.shape}, {b.shape}")
    if not np.isfinite(A.sum() + b.sum()):
        raise GeometryError("polytope: A and b must be finite")
    scale = max(1.0, float(np.abs(b).max()), float(np.abs(c).max()), float(np.abs(o).max()))
    tol = DISTANCE_REL_TOL * scale
    kern = _kernel()
    status, lower, upper, lam, _ = kern.solve_separation(o, c, M, A, b, los, tol)
    if status in (kern.NOT_SYMMETRIC, kern.NOT_POSITIVE_DEFINITE):
        raise GeometryError(f"{kern.STATUS_MESSAGES[status]}, got {M.tolist()}")
    if status != kern.OK:
        raise GeometryError(kern.STATUS_MESSAGES[status])
    if upper <= tol or not lower > 0.0:
        # Intersecting (or touching within tol): the distance is 0 and the kernel's lam is
        # arbitrary, so offer the face closest to separating them as the optimiser's guess.
        return 0.0, _best_single_face(o, c, M, A, b, los, lam, lower)
    return float(lower), lam


def _best_single_face(o, c, M, A, b, los, lam, lower) -> np.ndarray:
    norms = np.linalg.norm(A, axis=1)
    face = (A @ c - b - np.linalg.norm(A @ M, axis=1)) / norms
    if los:
        face = np.minimum(face, (A @ o - b) / norms)
    i = int(np.argmax(face))
    if np.isfinite(lower) and lower >= face[i]:
        return lam
    single = np.zeros(A.shape[0])
    single[i] = 1.0 / norms[i]
    return single


def ellipsoid_polytope_distance(
    center: object, shape: object, A: object, b: object
) -> tuple[float, np.ndarray]:
    """Exact Euclidean distance between an ellipsoid and a polytope, with an optimal dual ``lam``.

    Solved by a compiled interior-point method (see ``_separation_kernel``) that stops when the
    primal distance of explicit points and the dual bound of ``lam`` agree within ``1e-9`` times the
    scene size; the returned distance is the dual bound, so it never exceeds the true distance by
    more than rounding.

    Parameters
    ----------
    center : (3,) float
    shape : (3, 3) float, symmetric positive definite
    A : (k, 3) float, non-zero rows (unit rows recommended: then ``b`` offsets are metric)
    b : (k,) float

    Returns
    -------
    distance : float
        ``dist(E, P)`` (m); 0 if they intersect or touch.
    lam : (k,) float
        ``lam >= 0`` with ``|A^T lam| <= 1`` and ``dual_separation_margin(c, M, A, b, lam) ~=
        distance`` when separated. When they intersect, the single face that is closest to
        separating them (a starting guess for the NLP).

    Raises
    ------
    GeometryError
        Invalid ellipsoid or polytope, or an empty polytope.
    """
    return _separation(None, center, shape, A, b, los=False)


def box_pair_distances(
    origins: object,
    centers: object,
    shapes: object,
    lo: object,
    hi: object,
    los: object,
    with_duals: bool = False,
) -> np.ndarray | tuple[np.ndarray, np.ndarray]:
    """Exact distances of ``n`` (line-of-sight hull or ellipsoid, box) pairs in one compiled call.

    Pair ``i`` is ``conv({o_i} ∪ E_i)`` against the box ``lo_i <= y <= hi_i`` where ``los[i]``,
    else the ellipsoid ``E_i = {c_i + M_i z : |z| <= 1}`` alone: the distances of
    :func:`los_hull_distance` / :func:`ellipsoid_polytope_distance` for those boxes, without their
    per-call overhead (callers rank hundreds of pairs per plan).

    Parameters
    ----------
    origins, centers : (n, 3) float. shapes : (n, 3, 3) float. lo, hi : (n, 3) float.
    los : (n,) bool.

    with_duals : also return each pair's certifying dual.

    Returns
    -------
    (n,) float, and with ``with_duals`` the (n, 6) duals ``lam >= 0`` on the faces ``+x, +y, +z,
    -x, -y, -z`` (``|A^T lam| = 1``; zeros where the sets touch).
    """
    O = np.ascontiguousarray(origins, dtype=float).reshape(-1, 3)
    C = np.ascontiguousarray(centers, dtype=float).reshape(-1, 3)
    M = np.ascontiguousarray(shapes, dtype=float).reshape(-1, 3, 3)
    lo, hi = (np.ascontiguousarray(v, dtype=float).reshape(-1, 3) for v in (lo, hi))
    flags = np.ascontiguousarray(los, dtype=bool).reshape(-1)
    n = len(C)
    if not all(len(a) == n for a in (O, M, lo, hi, flags)):
        raise GeometryError(
            f"box_pair_distances: expected {n} of everything, got origins {len(O)}, shapes"
            f" {len(M)}, boxes {len(lo)}/{len(hi)}, los {len(flags)}"
        )
    if not np.isfinite(O.sum() + C.sum() + M.sum() + lo.sum() + hi.sum()):
        raise GeometryError("box_pair_distances: inputs must be finite")
    if np.any(lo > hi):
        raise GeometryError("box_pair_distances: every box needs lo <= hi")
    kern = _kernel()
    status, dist, lams = kern.box_distances(O, C, M, lo, hi, flags, DISTANCE_REL_TOL)
    bad = np.flatnonzero(status != kern.OK)
    if len(bad):
        i = int(bad[0])
        raise GeometryError(f"pair {i}: {kern.STATUS_MESSAGES[int(status[i])]}")
    return (dist, lams) if with_duals else dist


def boxes_apart(
    origin: np.ndarray | None,
    center: np.ndarray,
    shape: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    near: np.ndarray,
) -> bool:
    """Whether every box ``near`` lies at a positive distance from the ellipsoid ``E = {c + M z :
    |z| <= 1}`` (``origin`` None) or from the line-of-sight hull ``conv({o} ∪ E)``: the answer of
    :func:`box_pair_distances` (every distance > 0) in one compiled call, which stops at the first
    box that touches and settles a box without a solve where a plane through the box's point
    nearest ``c`` (for the hull also nearest ``o`` or the midpoint of o and c) shows it apart by
    more than the solve's tolerance.

    Parameters
    ----------
    origin : (3,) float or None. center : (3,) float. shape : (3, 3) float, symmetric positive
    definite. lo, hi : (n, 3) float, the boxes. near : (m,) int, indices of the boxes to judge.
    """
    kern = _kernel()
    c = _vec3(center, "center")
    o = c if origin is None else _vec3(origin, "origin")
    M = np.ascontiguousarray(shape, dtype=float)
    if M.shape != (3, 3) or not np.isfinite(M.sum()):
        raise GeometryError(f"shape: expected a finite (3, 3) matrix, got shape {M.shape}")
    near = np.ascontiguousarray(near, dtype=np.int64).reshape(-1)
    if not len(near):
        return True
    lo, hi = np.ascontiguousarray(lo, dtype=float), np.ascontiguousarray(hi, dtype=float)
    if lo.ndim != 2 or lo.shape[1:] != (3,) or hi.shape != lo.shape:
        raise GeometryError(f"boxes_apart: lo, hi must be (n, 3) alike, got {lo.shape}, {hi.shape}")
    if near.min() < 0 or near.max() >= len(lo):
        raise GeometryError(
            f"boxes_apart: near must index the {len(lo)} boxes, got {near.min()}..{near.max()}"
        )
    # only the judged boxes: the guard's map holds up to ~18,000 (validated where they are merged)
    blo, bhi = lo[near], hi[near]
    if not (np.isfinite(blo.sum() + bhi.sum()) and np.all(blo <= bhi)):
        raise GeometryError("boxes_apart: the boxes near must be finite with lo <= hi")
    status, apart = kern.boxes_apart(o, c, M, lo, hi, near, origin is not None, DISTANCE_REL_TOL)
    if status != kern.OK:
        raise GeometryError(f"{kern.STATUS_MESSAGES[status]}, got {M.tolist()}")
    return bool(apart)


def los_hull_distance(
    origin: object, center: object, shape: object, A: object, b: object
) -> tuple[float, np.ndarray]:
    """Exact distance between the line-of-sight hull ``conv({o} ∪ E)`` and a polytope.

    ``lam`` maximises ``min(los_hull_margins(o, c, M, A, b, lam))`` (the two bounds agree at the
    optimum unless the apex or the ellipsoid alone is the closest part of the hull). Accuracy is
    ~1e-8 of the scene size: that dual has a kink at its optimum, so it converges more slowly.

    Parameters
    ----------
    origin : (3,) float, the camera centre.
    center, shape, A, b : as in :func:`ellipsoid_polytope_distance`.

    Returns
    -------
    distance : float
    lam : (k,) float
    """
    return _separation(origin, center, shape, A, b, los=True)
