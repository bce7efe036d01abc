"""The certificate's compiled view search against a plain numpy form of the same definition."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.geometry.frustum import PinholeFrustum
from secure3d.geometry.polytope import cones_blocked
from secure3d.planning.certificate import TOP_VIEWS, _clear_views


def _rotation(yaw: float, pitch: float) -> np.ndarray:
    """Camera-to-world rotation: optical z forward along (yaw, pitch), x right, y down."""
    f = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    x = np.cross(f, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(f, x), f])


def _reference(points, owner, R, o, frustum, radius, lo, hi, tol):
    """Margins in each camera frame as (points x cameras) arrays, all cameras sorted, sight cones
    checked one camera at a time."""
    pc = np.einsum("cji,ncj->nci", R, points[:, None, :] - o[None])  # R_c^T (p - o_c)
    x, y, z = pc[..., 0], pc[..., 1], pc[..., 2]
    ah, av = 0.5 * frustum.hfov, 0.5 * frustum.vfov
    side_h = z * np.sin(ah) - np.abs(x) * np.cos(ah)
    side_v = z * np.sin(av) - np.abs(y) * np.cos(av)
    far = frustum.far - (np.linalg.norm(pc, axis=-1) if frustum.far_kind == "range" else z)
    V = np.minimum(np.minimum(side_h, side_v), far) - radius
    V = np.where(np.arange(len(R))[None, :] < owner[:, None], V, -np.inf)
    found = np.zeros(len(points), bool)
    best = np.full(len(points), -np.inf)
    for i in range(len(points)):
        for rank, cam in enumerate(np.argsort(-V[i])):
            m = V[i, cam]
            if not np.isfinite(m) or (rank >= TOP_VIEWS and m <= -tol):
                break
            if not cones_blocked(o[cam][None], points[i][None], lo, hi, radius)[0]:
                found[i], best[i] = True, m
                break
    return found, best, V.max(axis=1)


def _random_scene(rng, n_points: int, n_cams: int = 40):
    """Cameras along x looking roughly ahead, 15 random boxes, random points with random owners:
    (R, o, lo, hi, points, owner)."""
    o = np.column_stack([np.linspace(0, 4, n_cams), np.zeros(n_cams), np.full(n_cams, 1.0)])
    R = np.array([_rotation(y, p) for y, p in rng.uniform([-0.6, -0.2], [0.6, 0.2], (n_cams, 2))])
    lo = rng.uniform([0, -3, 0], [8, 3, 2], (15, 3))
    hi = lo + rng.uniform(0.1, 0.8, (15, 3))
    points = rng.uniform([0, -3, 0], [9, 3, 2], (n_points, 3))
    owner = rng.integers(0, n_cams + 1, n_points)
    return R, o, lo, hi, points, owner


@pytest.mark.parametrize("far_kind", ["depth", "range"])
def test_clear_views_match_the_numpy_definition(rng, far_kind):
    frustum = PinholeFrustum(hfov=np.radians(90), vfov=np.radians(60), far=6.0, far_kind=far_kind)
    R, o, lo, hi, points, owner = _random_scene(rng, 400)
    r, tol = 0.12, 1e-6
    found, best, raw, _ = _clear_views(points, owner, R, o, frustum, r, lo, hi, tol)
    want = _reference(points, owner, R, o, frustum, r, lo, hi, tol)
    np.testing.assert_array_equal(found, want[0])
    np.testing.assert_allclose(best, want[1], atol=1e-12)
    np.testing.assert_allclose(raw, want[2], atol=1e-12)
    # every verdict occurs: seen, seen only through an obstacle, never in view, no earlier camera
    occluded = ~found & (raw > -tol)
    assert found.sum() > 20 and occluded.sum() > 5 and (raw <= -tol).sum() > 5
    assert np.isneginf(raw[owner == 0]).all() and (owner == 0).any()


def test_a_view_search_cut_into_small_pieces_gives_the_same_answers(rng, monkeypatch):
    """The search looks at the clock between pieces of VIEW_WORK units; any cut gives the answers
    of one pass, and a deadline that passes between pieces stops it (issue 16)."""
    from secure3d.planning import _certificate_kernel, certificate, interrupt

    frustum = PinholeFrustum(hfov=np.radians(90), vfov=np.radians(60), far=6.0)
    R, o, lo, hi, points, owner = _random_scene(rng, 300)
    whole = _clear_views(points, owner, R, o, frustum, 0.12, lo, hi, 1e-6)
    calls = []
    kernel = _certificate_kernel.best_clear_views

    def counted(*args):
        calls.append(args[-2])
        return kernel(*args)

    monkeypatch.setattr(_certificate_kernel, "best_clear_views", counted)
    for work in (1, 700, 5000):
        monkeypatch.setattr(certificate, "VIEW_WORK", work)
        calls.clear()
        pieces = _clear_views(points, owner, R, o, frustum, 0.12, lo, hi, 1e-6)
        for a, b in zip(whole, pieces, strict=True):
            np.testing.assert_array_equal(a, b)
        assert len(calls) > 1 and calls == sorted(calls)  # resumed where the last piece stopped
        if work == 1:
            assert len(calls) >= (owner > 0).sum() // 2  # about a point per piece
    monkeypatch.setattr(certificate, "VIEW_WORK", 5000)
    with interrupt.deadline(0.0), pytest.raises(interrupt.BudgetSpent):
        _clear_views(points, owner, R, o, frustum, 0.12, lo, hi, 1e-6)


def test_many_blocked_views_are_walked_past_the_scans(rng):
    """A point behind a wall with a slot: the ~50 cameras that see it best are blocked, so the
    search goes past its first 16 maxima (then sorts) to the few that look through the slot."""
    frustum = PinholeFrustum(hfov=np.radians(120), vfov=np.radians(90), far=20.0)
    n_cams = 60
    o = np.column_stack([np.zeros(n_cams), np.linspace(-3, 3, n_cams), np.zeros(n_cams)])
    R = np.repeat(_rotation(0.0, 0.0)[None], n_cams, axis=0)
    # a wall at x in [2, 2.2] with a slot at y in [-1.45, -1.15]: sight lines from (0, c, 0) to the
    # point cross the wall at y = c / 2, so only cameras near c = -2.6 see through
    lo = np.array([[2.0, -10.0, -2.0], [2.0, -1.15, -2.0]])
    hi = np.array([[2.2, -1.45, 2.0], [2.2, 10.0, 2.0]])
    point = np.array([[4.0, 0.0, 0.0]])
    found, best, raw, _ = _clear_views(point, np.array([n_cams]), R, o, frustum, 0.05, lo, hi, 1e-6)
    want = _reference(point, np.array([n_cams]), R, o, frustum, 0.05, lo, hi, 1e-6)
    assert want[0][0] and found[0]
    assert best[0] == pytest.approx(want[1][0]) and best[0] < raw[0]


def test_the_shortcuts_of_the_cone_test_give_the_search_answer(rng):
    """The certificate kernel's per-box sight-cone test (the end ball first, tangent lower bounds)
    against the slab test and golden-section search of ``cone_blocked`` it shortcuts, on random
    cones that graze random boxes."""
    from secure3d.geometry._box_index_kernels import _cone_box_gap
    from secure3d.geometry._box_kernels import _hits
    from secure3d.planning._certificate_kernel import _blocks

    glo, ghi = np.empty(3), np.empty(3)
    blocked = grazing = 0
    for _ in range(5000):
        lo = rng.uniform(-1, 1, (1, 3))
        hi = lo + rng.uniform(0.05, 1.0, (1, 3))
        p0 = rng.uniform(-4, 4, 3)
        radius = rng.uniform(0.01, 0.4)
        # aim at about the radius from the box: many cones graze it
        c = rng.uniform(lo[0], hi[0]) + rng.normal(0, 1, 3) * rng.uniform(0, 2) * radius
        d = c - p0
        gap = _cone_box_gap(p0, d[0], d[1], d[2], lo[0], hi[0], radius)
        want = _hits(*p0, *d, lo[0] - radius, hi[0] + radius) and gap < 0.0
        assert _blocks(p0, c, radius, lo, hi, 0, glo, ghi) == want
        blocked += want
        grazing += 0.0 <= gap < 0.05
    assert blocked > 500 and grazing > 200
