"""Ellipsoid kernels, checked against dense surface sampling and independent constructions."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from secure3d.errors import GeometryError
from secure3d.geometry.ellipsoid import (
    check_ellipsoid,
    containment_margin,
    contains_points,
    ellipsoid_from_axes,
    halfspace_margins,
    support,
    surface_points,
    volume,
)


def random_ellipsoid(rng, lo=0.1, hi=1.5, spread=3.0):
    R = Rotation.random(random_state=int(rng.integers(1 << 30))).as_matrix()
    semi = rng.uniform(lo, hi, 3)
    return ellipsoid_from_axes(rng.uniform(-spread, spread, 3), R, semi) + (R, semi)


def unit_rows(rng, k):
    A = rng.standard_normal((k, 3))
    return A / np.linalg.norm(A, axis=1, keepdims=True)


def test_check_ellipsoid_names_the_problem():
    with pytest.raises(GeometryError, match="symmetric"):
        check_ellipsoid(np.zeros(3), [[1, 0.5, 0], [0, 1, 0], [0, 0, 1]])
    with pytest.raises(GeometryError, match="positive definite"):
        check_ellipsoid(np.zeros(3), np.diag([1.0, -1.0, 1.0]))
    with pytest.raises(GeometryError, match="positive definite"):
        check_ellipsoid(np.zeros(3), np.diag([1.0, 0.0, 1.0]))
    with pytest.raises(GeometryError, match="finite"):
        check_ellipsoid([0, np.nan, 0], np.eye(3))
    with pytest.raises(GeometryError, match="center"):
        check_ellipsoid(np.zeros(2), np.eye(3))
    with pytest.raises(GeometryError, match="batch"):
        check_ellipsoid(np.zeros((4, 3)), np.eye(3))


def test_support_matches_dense_surface_sampling(rng):
    for _ in range(5):
        c, M, _, semi = random_ellipsoid(rng)
        pts = surface_points(c, M, 100_000, rng)
        normals = unit_rows(rng, 20)
        sampled = (pts @ normals.T).max(axis=0)
        h = support(c, M, normals)
        # Sampling never exceeds the support; with 1e5 directions the gap is below ~1e-3 size.
        assert np.all(sampled <= h + 1e-12), "a surface point beats the support function"
        np.testing.assert_allclose(sampled, h, atol=2e-3 * semi.max(), err_msg="support too big")


def test_support_batches_like_a_loop(rng):
    ells = [random_ellipsoid(rng) for _ in range(6)]
    C = np.array([e[0] for e in ells])
    Ms = np.array([e[1] for e in ells])
    normals = unit_rows(rng, 7)
    batched = support(C, Ms, normals)
    assert batched.shape == (6, 7)
    for i in range(6):
        np.testing.assert_allclose(batched[i], support(C[i], Ms[i], normals), atol=1e-14)
    per_ellipsoid_normals = np.stack([unit_rows(rng, 7) for _ in range(6)])
    b = rng.uniform(0, 1, (6, 7))
    batched = halfspace_margins(C, Ms, per_ellipsoid_normals, b)
    for i in range(6):
        np.testing.assert_allclose(
            batched[i], b[i] - support(C[i], Ms[i], per_ellipsoid_normals[i]), atol=1e-14
        )


def test_containment_margin_sign_agrees_with_sampling(rng):
    decided = 0
    for _ in range(60):
        c, M, _, semi = random_ellipsoid(rng, spread=0.5)
        A = unit_rows(rng, 6)
        b = rng.uniform(0.5, 3.0, 6)
        margin = containment_margin(c, M, A, b)
        pts = surface_points(c, M, 20_000, rng)
        all_inside = bool(np.all(pts @ A.T <= b))
        if abs(margin) > 0.01 * semi.max():  # beyond the sampling resolution
            decided += 1
            assert (margin >= 0) == all_inside, f"margin {margin} but all_inside={all_inside}"
        # Per face: the sampled slack is never below the exact one, and close to it.
        slack = b - (pts @ A.T).max(axis=0)
        exact = halfspace_margins(c, M, A, b)
        assert np.all(slack >= exact - 1e-12)
        np.testing.assert_allclose(slack, exact, atol=0.01 * semi.max())
    assert decided > 40, "too few configurations away from the boundary to be a test"


def test_contains_points_built_in_the_unit_ball(rng):
    c, M, _, _ = random_ellipsoid(rng)
    z = rng.standard_normal((2000, 3))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    radius = rng.uniform(0, 2, 2000)
    radius = radius[np.abs(radius - 1) > 1e-6]
    pts = c + (z[: radius.size] * radius[:, None]) @ M.T
    np.testing.assert_array_equal(contains_points(c, M, pts), radius <= 1)


def test_surface_points_lie_on_the_surface(rng):
    c, M, _, _ = random_ellipsoid(rng)
    pts = surface_points(c, M, 5000, rng)
    assert pts.shape == (5000, 3)
    r = np.linalg.norm(np.linalg.solve(M, (pts - c).T), axis=0)
    np.testing.assert_allclose(r, 1.0, atol=1e-12)
    z = np.linalg.solve(M, (pts - c).T).T
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=0.05, err_msg="directions not uniform")


def test_volume_and_axes(rng):
    c, M, R, semi = random_ellipsoid(rng)
    assert volume(M) == pytest.approx(4 / 3 * np.pi * np.prod(semi), rel=1e-12)
    for i in range(3):  # each given axis is an eigenvector with its semi-axis as eigenvalue
        np.testing.assert_allclose(M @ R[:, i], semi[i] * R[:, i], atol=1e-12)
    # Monte Carlo volume with the (independent) membership test.
    half = semi.max()
    box = rng.uniform(-half, half, (200_000, 3)) + c
    mc = np.mean(contains_points(c, M, box)) * (2 * half) ** 3
    assert mc == pytest.approx(volume(M), rel=0.03)
    with pytest.raises(GeometryError, match="orthonormal"):
        ellipsoid_from_axes(c, 2 * R, semi)
    with pytest.raises(GeometryError, match="semi_axes"):
        ellipsoid_from_axes(c, R, [1, 0, 1])


def test_casadi_twins_match_numpy(rng):
    k = 5
    c, M = ca.SX.sym("c", 3), ca.SX.sym("M", 3, 3)
    A, b = ca.SX.sym("A", k, 3), ca.SX.sym("b", k)
    f = ca.Function(
        "f",
        [c, M, A, b],
        [support(c, M, A), halfspace_margins(c, M, A, b), containment_margin(c, M, A, b)],
    )
    A_fixed, b_fixed = unit_rows(rng, k), rng.uniform(0, 2, k)
    g = ca.Function("g", [c, M], [halfspace_margins(c, M, A_fixed, b_fixed)])
    for _ in range(20):
        cv, Mv, _, _ = random_ellipsoid(rng)
        Av, bv = unit_rows(rng, k), rng.uniform(0, 2, k)
        h, m, cm = (np.array(o).ravel() for o in f(cv, Mv, Av, bv))
        np.testing.assert_allclose(h, support(cv, Mv, Av), atol=1e-9)
        np.testing.assert_allclose(m, halfspace_margins(cv, Mv, Av, bv), atol=1e-9)
        np.testing.assert_allclose(cm[0], containment_margin(cv, Mv, Av, bv), atol=1e-9)
        np.testing.assert_allclose(
            np.array(g(cv, Mv)).ravel(), halfspace_margins(cv, Mv, A_fixed, b_fixed), atol=1e-9
        )
