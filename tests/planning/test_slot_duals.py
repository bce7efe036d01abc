"""Start duals of the obstacle slots: row margins, and the exact dual where the normal falls short."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.geometry.polytope import box_pair_distances
from secure3d.planning import lookback as lb
from secure3d.planning import slot_duals as sd


def test_the_exact_dual_makes_the_rows_the_distance_and_no_dual_does_better(rng, hull_box_pairs):
    """Weak duality: with any dual (lam >= 0, |A^T lam| <= 1) the smaller row is at most the
    distance between the sets; the certifying dual of box_pair_distances reaches it."""
    pairs = hull_box_pairs(rng, 3000, 0.6)
    origins, centres, shapes, lo, hi, los = pairs
    dist, exact = box_pair_distances(*pairs, with_duals=True)
    clear = dist > 1e-3
    margins = sd.dual_row_margins(exact, *pairs)
    assert np.allclose(margins[clear], dist[clear], atol=1e-6)
    normal = sd._normal_duals(centres, lo[:, None], hi[:, None])[:, 0]
    other = rng.random((len(dist), 6)) * rng.random((len(dist), 1))
    other /= np.maximum(1.0, np.linalg.norm(other[:, :3] - other[:, 3:], axis=1))[:, None]
    for lam in (normal, other):
        assert np.all(sd.dual_row_margins(lam, *pairs) <= dist + 1e-6)  # the solve's tolerance
    # the normal from the box to the centre ignores the apex: it falls short on many hulls
    short = sd.dual_row_margins(normal, *pairs) < dist - 0.1
    assert short[los & clear].mean() > 0.2


def test_apex_pad_counts_the_body_at_the_next_node():
    lam = np.array([[1.0, 0, 0, 0, 0, 0]])  # the +x face
    lo, hi = np.zeros((1, 3)), np.ones((1, 3))
    centres, origins = np.array([[3.0, 0.5, 0.5]]), np.array([[2.0, 0.5, 0.5]])
    shapes = 0.25 * np.eye(3)[None]
    args = (origins, centres, shapes, lo, hi, np.array([True]))
    assert sd.dual_row_margins(lam, *args) == pytest.approx(1.0)  # the apex: 2 - 1
    assert sd.dual_row_margins(lam, *args, apex_pad=True) == pytest.approx(0.75)
    assert sd.dual_row_margins(lam, *args[:5], np.array([False])) == pytest.approx(1.75)


@pytest.mark.parametrize("name", ["narrow_passage_50cm", "geb079_hidden_crate"])
def test_initial_duals_replace_only_the_normals_that_fall_short(maps_dir, name):
    import secure3d
    from secure3d.planning import problem_from_scenario
    from secure3d.planning.guess import initial_guess

    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / f"{name}.yaml"))
    X = initial_guess(problem, "secure").states
    assignment, _ = lb.adaptive_assignment(problem, X)
    slots = lb.select_slots(problem, "secure", X, assignment)
    lam = sd.initial_duals(problem, "secure", X, slots, assignment)
    lo, hi = slots[..., 0:3], slots[..., 3:6]
    normal = sd._normal_duals(lb.node_geometry(problem, X)["C"], lo, hi)
    baseline_centres = lb.node_geometry(problem, X)["P"]
    assert np.array_equal(
        sd.initial_duals(problem, "baseline", X, slots, assignment),
        sd._normal_duals(baseline_centres, slots[..., 0:3], slots[..., 3:6]),
    )
    # dual feasible everywhere
    assert np.all(lam >= 0)
    assert np.all(np.linalg.norm(lam[..., 0:3] - lam[..., 3:6], axis=-1) <= 1 + 1e-9)
    real = ~lb.empty_slots(problem, slots)
    o, c, M, los = lb.constrained_sets(problem, "secure", X, assignment)
    k, s = np.nonzero(real)
    sets = (o[k], c[k], M[k], lo[k, s], hi[k, s], los[k])
    before = sd.dual_row_margins(normal[k, s], *sets)
    after = sd.dual_row_margins(lam[k, s], *sets)
    dist = box_pair_distances(*sets)
    m = problem.options.margin
    fine = before >= m
    assert np.array_equal(lam[k[fine], s[fine]], normal[k[fine], s[fine]])  # kept as they were
    mended = ~fine & (dist > 1e-6)
    assert mended.sum() >= 10  # real scenes start many rows short with the normals
    assert np.allclose(after[mended], dist[mended], atol=1e-6)  # the best any dual can do
    assert (after < m).sum() < (before < m).sum()


def test_row_margins_name_a_misshapen_argument():
    from secure3d.errors import GeometryError

    one = (np.zeros((1, 3)), np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)), np.ones((1, 3)))
    with pytest.raises(GeometryError, match=r"lam must have shape \(1, 6\), got \(1, 3\)"):
        sd.dual_row_margins(np.zeros((1, 3)), *one, np.array([True]))
    with pytest.raises(GeometryError, match="los must have shape"):
        sd.dual_row_margins(np.zeros((1, 6)), *one, np.array([True, False]))


def test_empty_slots_names_a_misshapen_slot_array():
    from types import SimpleNamespace

    from secure3d.errors import PlanningError

    problem = SimpleNamespace(bounds_hi=np.ones(3))
    far = np.full((2, 3, 6), 1001.0)
    far[0, 1, :3] = 0.0  # one real box
    assert lb.empty_slots(problem, far).tolist() == [[True, False, True], [True, True, True]]
    with pytest.raises(PlanningError, match=r"shape \(K, S, 6\), got \(2, 3\)"):
        lb.empty_slots(problem, far[..., 0])
