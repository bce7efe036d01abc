"""Exact ball-in-ellipsoid clearance against brute force over the boundary."""

from __future__ import annotations

import numpy as np

from secure3d.reactive._clearance import clearance, required_inflation


def _random_ellipsoids(rng, m):
    A = rng.normal(size=(m, 3, 3))
    M = np.einsum("nij,nkj->nik", A, A) + 0.2 * np.eye(3)
    return rng.normal(size=(m, 3)), M


def _brute_distance_to_boundary(c, M, p, rng, n=100_000):
    z = rng.normal(size=(n, 3))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    return np.linalg.norm(c + z @ M.T - p, axis=1).min()


def test_clearance_matches_brute_force(rng):
    m = 60
    C, M = _random_ellipsoids(rng, m)
    P = C + np.einsum("nij,nj->ni", M, rng.normal(size=(m, 3)) * 0.8)
    cl = clearance(P, np.arange(m), C, M)
    for k in range(m):
        inside = np.linalg.norm(np.linalg.solve(M[k], P[k] - C[k])) <= 1
        brute = _brute_distance_to_boundary(C[k], M[k], P[k], rng)
        assert (cl[k] >= 0) == inside
        # Sampling the boundary over-estimates the distance, by little with 1e5 samples.
        assert abs(cl[k]) <= brute + 1e-9, (k, cl[k], brute)
        assert abs(cl[k]) >= brute - 0.02 * (1 + brute), (k, cl[k], brute)


def test_clearance_on_axisymmetric_degenerate_cases():
    """Points on the axis of a prolate spheroid: the nearest boundary point is off-axis."""
    M = np.tile(np.diag([3.0, 1.0, 1.0]), (4, 1, 1))
    P = np.array([[0.0, 0, 0], [1.0, 0, 0], [2.5, 0, 0], [0.0, 0.5, 0]])
    cl = clearance(P, np.arange(4), np.zeros((4, 3)), M)
    # Closed form: nearest point (x, rho) on x^2/9 + rho^2 = 1 to (a, 0): x = 9a/8.
    expect = [
        1.0,
        np.sqrt(1 - 8 / 64),
        np.sqrt((9 * 2.5 / 8 - 2.5) ** 2 + 1 - (9 * 2.5 / 8) ** 2 / 9),
        0.5,
    ]
    np.testing.assert_allclose(cl, expect, atol=1e-9)


def test_skipped_points_get_a_valid_lower_bound(rng):
    C, M = _random_ellipsoids(rng, 20)
    P = C + 0.05 * rng.normal(size=(20, 3))
    exact = clearance(P, np.arange(20), C, M)
    bound = clearance(P, np.arange(20), C, M, enough=0.0)
    assert np.all(bound <= exact + 1e-12)


def test_required_inflation_is_minimal_and_sufficient(rng):
    m, n, r = 15, 40, 0.2
    C, M = _random_ellipsoids(rng, m)
    P = np.repeat(C, n, axis=0) + rng.normal(size=(m * n, 3))
    off = np.arange(0, m * n + 1, n)
    owner = np.repeat(np.arange(m), n)
    eta = required_inflation(P, off, C, M, r, tol=1e-7)
    eye = np.eye(3)[None]
    ok = clearance(P, owner, C, M + eta[:, None, None] * eye)
    assert ok.min() >= r - 1e-9
    short = clearance(P, owner, C, M + (eta[:, None, None] - 1e-5) * eye)
    worst = np.array([short[owner == k].min() for k in range(m)])
    assert np.all(worst < r), "a smaller inflation would also do: not minimal"
