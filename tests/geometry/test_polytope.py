"""Polytopes and separation, cross-checked against python-fcl, scipy and dense sampling."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial import Delaunay, cKDTree
from scipy.spatial.transform import Rotation

from secure3d._deps import fcl
from secure3d.errors import GeometryError
from secure3d.geometry.ellipsoid import ellipsoid_from_axes, surface_points
from secure3d.geometry.polytope import (
    box_halfspaces,
    box_pair_distances,
    box_signed_distance,
    boxes_apart,
    boxes_halfspaces,
    convex_hull_halfspaces,
    dual_separation_margin,
    ellipsoid_polytope_distance,
    los_hull_distance,
    los_hull_margins,
    min_box_distance,
    segment_box_intersects,
)


def random_box(rng):
    lo = rng.uniform(-1, 1, 3)
    return lo, lo + rng.uniform(0.2, 2.0, 3)


def random_ellipsoid(rng, spread=4.0):
    U = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
    semi = rng.uniform(0.1, 1.5, 3)
    c, M = ellipsoid_from_axes(rng.uniform(-spread, spread, 3), U, semi)
    return c, M, U, semi


def fcl_distance(c, U, semi, lo, hi):
    f = fcl()
    ell = f.CollisionObject(f.Ellipsoid(*semi), f.Transform(U, c))
    box = f.CollisionObject(f.Box(*(hi - lo)), f.Transform(np.eye(3), (hi + lo) / 2))
    return f.distance(ell, box, f.DistanceRequest(), f.DistanceResult())


def random_feasible_lams(rng, A, n):
    lam = rng.exponential(1.0, (n, A.shape[0])) * (rng.random((n, A.shape[0])) < 0.6)
    norm = np.linalg.norm(lam @ A, axis=1)
    keep = norm > 1e-9
    return lam[keep] / norm[keep, None] * rng.uniform(0.1, 1.0, (keep.sum(), 1))


# ---------------------------------------------------------------------------------------------
# Construction and point / segment queries
# ---------------------------------------------------------------------------------------------


def test_box_halfspaces_describe_the_box(rng):
    lo, hi = random_box(rng)
    A, b = box_halfspaces(lo, hi)
    p = rng.uniform(lo - 1, hi + 1, (5000, 3))
    np.testing.assert_array_equal(
        np.all(p @ A.T <= b, axis=1), np.all((p >= lo) & (p <= hi), axis=1)
    )
    los, his = np.array([random_box(rng) for _ in range(4)]).transpose(1, 0, 2)
    As, bs = boxes_halfspaces(los, his)
    assert As.shape == (4, 6, 3) and bs.shape == (4, 6)
    for i in range(4):
        np.testing.assert_array_equal(bs[i], box_halfspaces(los[i], his[i])[1])
    with pytest.raises(GeometryError, match="lo must not exceed hi"):
        box_halfspaces([0, 0, 1], [1, 1, 0])


def test_convex_hull_merges_coplanar_facets_and_matches_delaunay(rng):
    cube = np.array([[x, y, z] for x in (0, 1) for y in (0, 2) for z in (0, 3)], dtype=float)
    extra = np.r_[rng.uniform(0, 1, (20, 3)) * [1, 2, 3], [[0.5, 1.0, 3.0], [1.0, 0.3, 0.2]]]
    A, b = convex_hull_halfspaces(np.r_[cube, extra])
    assert A.shape == (6, 3), "coplanar triangles must merge into one face per side"
    np.testing.assert_allclose(np.linalg.norm(A, axis=1), 1.0, atol=1e-12)
    order = np.lexsort(A.T)
    box_A, box_b = box_halfspaces([0, 0, 0], [1, 2, 3])
    ref = np.lexsort(box_A.T)
    np.testing.assert_allclose(A[order], box_A[ref], atol=1e-12)
    np.testing.assert_allclose(b[order], box_b[ref], atol=1e-12)

    V = rng.standard_normal((30, 3)) * [1, 2, 0.5]
    A, b = convex_hull_halfspaces(V)
    assert np.all(V @ A.T <= b + 1e-9)
    assert np.all(np.sum(np.abs(V @ A.T - b) < 1e-9, axis=0) >= 3), "a face touches < 3 points"
    q = rng.standard_normal((3000, 3)) * 1.5
    np.testing.assert_array_equal(np.all(q @ A.T <= b, axis=1), Delaunay(V).find_simplex(q) >= 0)
    with pytest.raises(GeometryError, match="flat|degenerate"):
        convex_hull_halfspaces(np.c_[rng.standard_normal((10, 2)), np.zeros(10)])
    with pytest.raises(GeometryError, match="n >= 4"):
        convex_hull_halfspaces(V[:3])


def test_box_signed_distance_matches_brute_force(rng):
    lo = np.array([[0.0, 0.0, 0.0], [2.0, -1.0, 0.5]])
    hi = np.array([[1.0, 2.0, 0.5], [3.0, 0.0, 1.5]])
    p = rng.uniform(-1.5, 4.0, (400, 3))
    d = box_signed_distance(p, lo, hi)
    assert d.shape == (400, 2)
    step = 0.01
    for j in range(2):
        g = [np.arange(lo[j, i], hi[j, i] + step / 2, step) for i in range(3)]
        grid = np.stack(np.meshgrid(*g, indexing="ij"), -1).reshape(-1, 3)
        on_surface = np.any(
            np.isclose(grid, lo[j], atol=1e-9) | np.isclose(grid, hi[j], atol=1e-9), axis=1
        )
        surf = grid[on_surface]
        brute = cKDTree(surf).query(p)[0]
        inside = np.all((p >= lo[j]) & (p <= hi[j]), axis=1)
        np.testing.assert_allclose(d[:, j], np.where(inside, -brute, brute), atol=step)
        assert np.all((d[:, j] < 0) == inside)
    np.testing.assert_array_equal(min_box_distance(p, lo, hi), d.min(axis=1))
    assert np.all(min_box_distance(p, np.zeros((0, 3)), np.zeros((0, 3))) == np.inf)


def test_segment_box_intersects_matches_dense_sampling(rng):
    lo = np.array([[0.0, 0.0, 0.0], [2.0, -1.0, 0.5], [-1.0, 1.0, -1.0]])
    hi = np.array([[1.0, 2.0, 0.5], [3.0, 0.0, 1.5], [-0.5, 1.2, 2.0]])
    p0 = rng.uniform(-2, 4, (300, 3))
    p1 = rng.uniform(-2, 4, (300, 3))
    # Axis-parallel and zero-length segments exercise the slab test's special cases.
    p1[:40, 1:] = p0[:40, 1:]
    p1[40:50] = p0[40:50]
    p0[50:60] = [0.5, 1.0, 0.25]
    p1[60:100] = rng.uniform(lo[0], hi[0], (40, 3))  # ending inside box 0
    # Stopping 1 mm short of box 0's -x face, and ending exactly on it.
    p0[100:102] = [-1.0, 1.0, 0.25]
    p1[100:102] = [[-1e-3, 1.0, 0.25], [0.0, 1.0, 0.25]]
    hit = segment_box_intersects(p0, p1, lo, hi)
    assert hit.shape == (300, 3)
    t = np.linspace(0, 1, 4001)
    samples = p0[:, None] + t[None, :, None] * (p1 - p0)[:, None]  # (n, T, 3)
    step = np.linalg.norm(p1 - p0, axis=1) / 4000
    for j in range(3):
        d = box_signed_distance(samples.reshape(-1, 3), lo[j : j + 1], hi[j : j + 1])
        dmin = d.reshape(300, -1).min(axis=1)
        assert np.all(hit[dmin <= 0, j]), "a sampled point is inside but the slab test says miss"
        # A hit not confirmed by a sample must pass within one sampling step of the box.
        assert np.all(dmin[hit[:, j]] <= step[hit[:, j]] + 1e-12)
    assert hit[50:100, 0].all() and not hit[100, 0] and hit[101, 0]


# ---------------------------------------------------------------------------------------------
# Ellipsoid-polytope separation
# ---------------------------------------------------------------------------------------------


def test_distance_matches_fcl_and_duality(rng):
    separated = 0
    for _ in range(60):
        c, M, U, semi = random_ellipsoid(rng)
        lo, hi = random_box(rng)
        A, b = box_halfspaces(lo, hi)
        dist, lam = ellipsoid_polytope_distance(c, M, A, b)
        ref = fcl_distance(c, U, semi, lo, hi)
        if ref > 1e-3:
            separated += 1
            assert dist == pytest.approx(ref, abs=1e-3), "differs from fcl (GJK tolerance)"
            assert np.all(lam >= 0) and np.linalg.norm(A.T @ lam) <= 1 + 1e-12
            np.testing.assert_allclose(
                dual_separation_margin(c, M, A, b, lam, eps=1e-9), dist, atol=1e-8
            )
            for other in random_feasible_lams(rng, A, 50):  # weak duality
                assert dual_separation_margin(c, M, A, b, other, eps=0.0) <= dist + 1e-9
        else:
            assert dist == 0.0
    assert separated > 30


def test_distance_matches_dense_sampling(rng):
    for _ in range(15):
        c, M, _, semi = random_ellipsoid(rng, spread=3.0)
        lo, hi = random_box(rng)
        dist, _ = ellipsoid_polytope_distance(c, M, *box_halfspaces(lo, hi))
        # Sample the solid ellipsoid's surface; if any surface point is in the box they touch.
        pts = surface_points(c, M, 40_000, rng)
        sampled = box_signed_distance(pts, lo[None], hi[None]).min()
        if sampled <= 0:
            assert dist == 0.0
        else:
            assert dist <= sampled + 1e-12, "sampling found a closer pair than the solver"
            assert dist == pytest.approx(sampled, abs=0.01 * semi.max())


def slsqp_primal(c, M, A, b, y0):
    """Independent primal solve of min |c + M z - y| s.t. |z| <= 1, A y <= b: returns (z, y)."""
    J = np.c_[M, -np.eye(3)]
    res = minimize(
        lambda w: np.sum((c + J @ w) ** 2),
        np.r_[np.zeros(3), y0],
        jac=lambda w: 2 * J.T @ (c + J @ w),
        method="SLSQP",
        constraints=[
            {
                "type": "ineq",
                "fun": lambda w: 1 - w[:3] @ w[:3],
                "jac": lambda w: np.r_[-2 * w[:3], np.zeros(3)],
            },
            {
                "type": "ineq",
                "fun": lambda w: b - A @ w[3:],
                "jac": lambda w: np.c_[np.zeros((len(b), 3)), -A],
            },
        ],
        options={"ftol": 1e-14, "maxiter": 500},
    )
    return res.x


def test_distance_to_general_polytopes_matches_slsqp(rng):
    for _ in range(10):
        V = rng.standard_normal((12, 3)) + rng.uniform(-2, 2, 3)
        A, b = convex_hull_halfspaces(V)
        c, M, _, _ = random_ellipsoid(rng)
        dist, lam = ellipsoid_polytope_distance(c, M, A, b)
        w = slsqp_primal(c, M, A, b, V.mean(axis=0))
        assert w[:3] @ w[:3] <= 1 + 1e-9 and np.all(A @ w[3:] <= b + 1e-9)
        primal = np.linalg.norm(c + M @ w[:3] - w[3:])
        assert dist <= primal + 1e-9
        assert dist == pytest.approx(primal, abs=1e-5)
        if dist > 0:
            assert dual_separation_margin(c, M, A, b, lam, eps=0.0) == pytest.approx(dist, abs=1e-8)


def test_halfspace_and_degenerate_polytopes(rng):
    c, M, _, _ = random_ellipsoid(rng)
    n = np.array([0.0, 0.6, 0.8])
    offset = n @ c - 3.0
    # Unbounded P (one half-space n.y <= offset): distance = n.c - offset - |M n| in closed form.
    dist, lam = ellipsoid_polytope_distance(c, M, n[None], [offset])
    assert dist == pytest.approx(3.0 - np.linalg.norm(M @ n), abs=1e-8)
    np.testing.assert_allclose(lam, [1.0], atol=1e-9)
    with pytest.raises(GeometryError, match="empty"):
        ellipsoid_polytope_distance(c, M, np.array([[1.0, 0, 0], [-1.0, 0, 0]]), [0.0, -1.0])
    with pytest.raises(GeometryError, match="positive definite"):
        ellipsoid_polytope_distance(c, np.diag([1.0, 0.0, 1.0]), *box_halfspaces([0] * 3, [1] * 3))
    with pytest.raises(GeometryError, match="symmetric"):
        ellipsoid_polytope_distance(
            c, M + np.triu(np.ones((3, 3)), 1), *box_halfspaces([0] * 3, [1] * 3)
        )


def test_intersecting_gives_zero_and_a_usable_face(rng):
    A, b = box_halfspaces([0, 0, 0], [2, 2, 2])
    _, M = ellipsoid_from_axes(np.zeros(3), np.eye(3), [0.5, 0.5, 0.5])
    for c in ([1.0, 1.0, 1.0], [2.3, 1.0, 1.0], [2.2, 2.2, 1.0]):
        dist, lam = ellipsoid_polytope_distance(c, M, A, b)
        assert dist == 0.0
        assert np.all(lam >= 0) and np.linalg.norm(A.T @ lam) <= 1 + 1e-12
    # Near the +x face the guess must be that face.
    _, lam = ellipsoid_polytope_distance([2.3, 1.0, 1.0], M, A, b)
    np.testing.assert_allclose(lam, [1, 0, 0, 0, 0, 0])


# ---------------------------------------------------------------------------------------------
# Line-of-sight hull
# ---------------------------------------------------------------------------------------------


def hull_samples(o, c, M, rng, n_dirs=3000, n_steps=200):
    surf = surface_points(c, M, n_dirs, rng)
    t = np.linspace(0, 1, n_steps)
    return (o + t[None, :, None] * (surf - o)[:, None, :]).reshape(-1, 3)


def test_los_hull_distance_agrees_with_sampling(rng):
    hits = misses = 0
    for _ in range(25):
        c, M, _, semi = random_ellipsoid(rng, spread=3.0)
        o = rng.uniform(-4, 4, 3)
        lo, hi = random_box(rng)
        A, b = box_halfspaces(lo, hi)
        dist, lam = los_hull_distance(o, c, M, A, b)
        pts = hull_samples(o, c, M, rng)
        sampled = box_signed_distance(pts, lo[None], hi[None]).min()
        if sampled <= 0:
            hits += 1
            assert dist == 0.0, "a line-of-sight sample is inside the box"
        else:
            assert dist <= sampled + 1e-12
            if dist > 0:
                misses += 1
                assert dist == pytest.approx(sampled, abs=0.02 * max(semi.max(), 1.0))
                apex, ell = los_hull_margins(o, c, M, A, b, lam, eps=1e-9)
                assert min(apex, ell) == pytest.approx(dist, abs=1e-7)
                for other in random_feasible_lams(rng, A, 30):
                    assert min(los_hull_margins(o, c, M, A, b, other, eps=0.0)) <= dist + 1e-9
        # The hull contains E and o: it is never farther than either.
        assert dist <= ellipsoid_polytope_distance(c, M, A, b)[0] + 1e-9
        assert dist <= max(box_signed_distance(o[None], lo[None], hi[None])[0, 0], 0) + 1e-9
    assert hits >= 3 and misses >= 5


def test_los_hull_blocked_by_wall_between_camera_and_ellipsoid():
    # Camera and ellipsoid are both clear of the wall, but the wall blocks the view.
    A, b = box_halfspaces([1.0, -1.0, -1.0], [1.2, 1.0, 1.0])
    _, M = ellipsoid_from_axes(np.zeros(3), np.eye(3), [0.3, 0.3, 0.3])
    c = np.array([3.0, 0.0, 0.0])
    assert ellipsoid_polytope_distance(c, M, A, b)[0] == pytest.approx(1.5, abs=1e-8)
    assert los_hull_distance([0.0, 0.0, 0.0], c, M, A, b)[0] == 0.0
    # Raised well above the wall the view is clear; the hull's closest point is an edge.
    dist, lam = los_hull_distance([0.0, 0.0, 3.0], c + [0, 0, 3.0], M, A, b)
    assert dist > 1.0
    assert min(los_hull_margins([0.0, 0.0, 3.0], c + [0, 0, 3.0], M, A, b, lam, 1e-9)) == (
        pytest.approx(dist, abs=1e-7)
    )


# ---------------------------------------------------------------------------------------------
# CasADi twins
# ---------------------------------------------------------------------------------------------


def test_casadi_twins_match_numpy(rng):
    o, c, M = ca.SX.sym("o", 3), ca.SX.sym("c", 3), ca.SX.sym("M", 3, 3)
    lam = ca.SX.sym("lam", 6)
    A, b = box_halfspaces([0, 0, 0], [1, 2, 1])
    dual = dual_separation_margin(c, M, A, b, lam, eps=1e-4)
    apex, ell = los_hull_margins(o, c, M, A, b, lam, eps=1e-4)
    f = ca.Function("f", [o, c, M, lam], [dual, apex, ell, ca.gradient(dual, lam)])
    for _ in range(20):
        cv, Mv, _, _ = random_ellipsoid(rng)
        ov = rng.uniform(-3, 3, 3)
        lv = rng.exponential(1.0, 6)
        d_s, a_s, e_s, _ = (np.array(x).ravel() for x in f(ov, cv, Mv, lv))
        assert d_s[0] == pytest.approx(dual_separation_margin(cv, Mv, A, b, lv, eps=1e-4), abs=1e-9)
        a_n, e_n = los_hull_margins(ov, cv, Mv, A, b, lv, eps=1e-4)
        assert a_s[0] == pytest.approx(a_n, abs=1e-9) and e_s[0] == pytest.approx(e_n, abs=1e-9)
    # The smooth norm keeps the gradient finite where A^T lam = 0 (opposite faces balanced).
    grad = np.array(f(np.zeros(3), np.ones(3), np.eye(3), np.r_[1.0, 0, 0, 1.0, 0, 0])[3])
    assert np.all(np.isfinite(grad))


def test_boxes_apart_answers_as_the_exact_distances_do():
    """boxes_apart (the guard's quick tests) is the exact distances' verdict, every distance > 0,
    for ellipsoids and line-of-sight hulls among random boxes: far, near, touching and a hair
    (1e-7 m) apart, where its separating planes and its solves must both be right."""
    rng = np.random.default_rng(5)
    verdicts = {True: 0, False: 0}
    for trial in range(400):
        c, M, _, _ = random_ellipsoid(rng, spread=1.5)
        o = rng.uniform(-4, 4, 3)
        lo = rng.uniform(-3, 3, (5, 3))
        hi = lo + rng.uniform(0.05, 1.5, (5, 3))
        if trial % 4 == 0:  # a box face a hair beyond E's extent along x
            x_max = c[0] + np.linalg.norm(M[0])
            lo[0, 0], hi[0, 0] = x_max + 1e-7, x_max + 0.5
            lo[0, 1:], hi[0, 1:] = c[1:] - 0.2, c[1:] + 0.2
        near = rng.permutation(5)[: rng.integers(1, 6)]
        for los in (False, True):
            origin = o if los else None
            d = box_pair_distances(
                np.broadcast_to(o if los else c, (len(near), 3)),
                np.broadcast_to(c, (len(near), 3)),
                np.broadcast_to(M, (len(near), 3, 3)),
                lo[near],
                hi[near],
                np.full(len(near), los),
            )
            expected = bool(np.all(d > 0.0))
            assert boxes_apart(origin, c, M, lo, hi, near) == expected, (trial, los, d)
            verdicts[expected] += 1
    assert min(verdicts.values()) > 100, verdicts  # both answers are exercised
    assert boxes_apart(None, c, M, lo, hi, np.zeros(0, int))  # no boxes: apart
    with pytest.raises(GeometryError, match="positive definite"):
        boxes_apart(None, c, np.diag([1.0, 1.0, -1.0]), lo, hi, np.arange(5))
    with pytest.raises(GeometryError, match=r"near must index the 5 boxes, got 0\.\.5"):
        boxes_apart(None, c, M, lo, hi, np.arange(6))
    with pytest.raises(GeometryError, match=r"lo, hi must be \(n, 3\) alike"):
        boxes_apart(None, c, M, lo, hi[:4], np.arange(4))
    with pytest.raises(GeometryError, match="finite with lo <= hi"):
        boxes_apart(None, c, M, hi, lo, np.arange(5))


def test_box_pair_distances_match_the_pairwise_solvers():
    rng = np.random.default_rng(11)
    O, C, M, lo, hi, los, expected = [], [], [], [], [], [], []
    for i in range(60):
        c, m, _, _ = random_ellipsoid(rng)
        o = rng.uniform(-5, 5, 3)
        b_lo, b_hi = random_box(rng)
        A, b = box_halfspaces(b_lo, b_hi)
        flag = bool(i % 2)
        d = (
            los_hull_distance(o, c, m, A, b)[0]
            if flag
            else ellipsoid_polytope_distance(c, m, A, b)[0]
        )
        O.append(o), C.append(c), M.append(m), lo.append(b_lo), hi.append(b_hi), los.append(flag)
        expected.append(d)
    got = box_pair_distances(O, C, M, lo, hi, los)
    assert np.allclose(got, expected, atol=1e-9)
    # the duals certify those distances (weak duality, DESIGN.md section 4)
    dist, lam = box_pair_distances(O, C, M, lo, hi, los, with_duals=True)
    np.testing.assert_array_equal(dist, got)
    for i in np.flatnonzero(dist > 0):
        A, b = box_halfspaces(lo[i], hi[i])
        assert np.all(lam[i] >= 0) and np.isclose(np.linalg.norm(A.T @ lam[i]), 1.0)
        bound = lam[i] @ (A @ C[i] - b) - np.linalg.norm(M[i] @ (A.T @ lam[i]))
        if los[i]:
            bound = min(bound, lam[i] @ (A @ O[i] - b))
        assert bound == pytest.approx(dist[i], abs=1e-7)
    assert np.all(lam[dist == 0] == 0)
    assert (np.asarray(expected) == 0).any() and (np.asarray(expected) > 0).any()
    assert box_pair_distances(
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        np.zeros((0, 3, 3)),
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        [],
    ).shape == (0,)


def test_box_pair_distances_reject_bad_input():
    c, m = np.zeros(3), np.eye(3)
    with pytest.raises(GeometryError, match="expected 2 of everything"):
        box_pair_distances([c, c], [c, c], [m], [c, c], [c + 1, c + 1], [True, False])
    with pytest.raises(GeometryError, match="lo <= hi"):
        box_pair_distances([c], [c], [m], [c + 1], [c], [False])
    with pytest.raises(GeometryError, match="pair 0"):
        box_pair_distances([c], [c], [-m], [c + 2], [c + 3], [False])
