"""Compiled box queries used by the planner and the certificate, against brute-force references."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.errors import GeometryError
from secure3d.geometry.frustum import PinholeFrustum, frustum_halfspaces
from secure3d.geometry.polytope import (
    box_signed_distance,
    cones_blocked,
    inside_any_box,
    min_box_distance,
    segment_box_intersects,
    segments_blocked,
)


@pytest.fixture
def boxes(rng):
    lo = rng.uniform(-2, 2, (12, 3))
    return lo, lo + rng.uniform(0.1, 1.0, (12, 3))


def test_min_box_distance_matches_the_numpy_matrix(rng, boxes):
    pts = rng.uniform(-3, 3, (500, 3))
    np.testing.assert_allclose(
        min_box_distance(pts, *boxes),
        box_signed_distance(pts, *boxes).min(axis=1),
        atol=1e-12,
        err_msg="compiled min distance vs numpy signed distances",
    )


def test_inside_any_box_is_a_negative_min_distance(rng, boxes):
    lo, hi = boxes
    pts = np.concatenate([rng.uniform(-3, 3, (500, 3)), lo, hi, 0.5 * (lo + hi)])
    inside = inside_any_box(pts, lo, hi)
    np.testing.assert_array_equal(inside, min_box_distance(pts, lo, hi) < 0.0)
    assert inside[524:].all() and inside[:500].any() and not inside[:500].all()
    assert not inside_any_box(pts, np.empty((0, 3)), np.empty((0, 3))).any()


def test_segments_blocked_is_any_of_the_matrix(rng, boxes):
    p0, p1 = rng.uniform(-3, 3, (400, 3)), rng.uniform(-3, 3, (400, 3))
    np.testing.assert_array_equal(
        segments_blocked(p0, p1, *boxes), segment_box_intersects(p0, p1, *boxes).any(axis=1)
    )


def _cone_hits_by_sampling(apex, centre, lo, hi, radius, rng, n=60_000):
    # points of conv({apex} ∪ B(centre, radius)) = apex + t (q - apex), q in the ball
    d = rng.normal(size=(n, 3))
    q = centre + radius * d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(
        0, 1, (n, 1)
    ) ** (1 / 3)
    t = rng.uniform(0, 1, (n, 1))
    y = apex + t * (q - apex)
    return bool(
        np.any(
            np.all((y >= lo) & (y <= hi), axis=-1)[:, None]
            if lo.ndim == 1
            else np.all((y[:, None] >= lo) & (y[:, None] <= hi), axis=-1)
        )
    )


def test_cones_blocked_agrees_with_sampling_away_from_tangency(rng):
    lo, hi = np.array([[0.0, 0.0, 0.0]]), np.array([[1.0, 1.0, 1.0]])
    checked = 0
    for _ in range(300):
        apex, centre = rng.uniform(-2, 3, 3), rng.uniform(-2, 3, 3)
        r = rng.uniform(0.05, 0.6)
        exact = cones_blocked(apex[None], centre[None], lo, hi, r)[0]
        grown = cones_blocked(apex[None], centre[None], lo, hi, r * 1.05)[0]
        shrunk = cones_blocked(apex[None], centre[None], lo, hi, r * 0.95)[0]
        if grown != shrunk:
            continue  # near tangency: sampling cannot settle it
        checked += 1
        # the formula (min over t of dist(apex + t (centre - apex), box) - t r < 0) on a dense grid
        ts = np.linspace(0, 1, 20_001)[:, None]
        y = apex + ts * (centre - apex)
        gap = np.linalg.norm(np.maximum(np.maximum(lo - y, y - hi), 0), axis=1) - ts[:, 0] * r
        assert exact == bool(gap.min() < 0), (apex, centre, r)
        # the geometry: sampled points of the cone (misses only thin intersections)
        if not exact:
            assert not _cone_hits_by_sampling(apex, centre, lo[0], hi[0], r, rng), (apex, centre, r)
    assert checked > 200
    with pytest.raises(GeometryError, match="radius"):
        cones_blocked(np.zeros((1, 3)), np.ones((1, 3)), lo, hi, -1.0)


def test_cone_through_a_gap_is_clear_only_if_its_width_fits():
    lo = np.array(
        [[1.0, -2.0, -2.0], [1.0, 0.3, -2.0]]
    )  # a wall at x in [1, 1.2] with a slot |y| < 0.3
    hi = np.array([[1.2, -0.3, 2.0], [1.2, 2.0, 2.0]])
    apex, centre = np.array([[0.0, 0.0, 0.0]]), np.array([[2.0, 0.0, 0.0]])
    assert not cones_blocked(apex, centre, lo, hi, 0.2)[0]
    assert cones_blocked(apex, centre, lo, hi, 0.7)[0], (
        "at x = 1 the cone is 0.35 wide: it hits the slot sides"
    )


def test_range_frustum_facets_stay_inside_the_range_sphere(rng):
    fr = PinholeFrustum(hfov=np.radians(120), vfov=np.radians(80), far=2.0, far_kind="range")
    A, b = frustum_halfspaces(np.eye(3), np.zeros(3), fr)
    assert A.shape[0] == fr.n_faces > 5
    pts = rng.uniform(-2.5, 2.5, (200_000, 3))
    inside = np.all(pts @ A.T <= b, axis=1)
    assert inside.sum() > 1000
    assert np.linalg.norm(pts[inside], axis=1).max() <= 2.0 + 1e-9
    # and it keeps most of the range along the axis (a single far plane would keep far*cos(diag))
    assert np.all(np.array([0.0, 0.0, 1.9]) @ A.T <= b)
