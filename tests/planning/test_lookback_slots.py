"""Obstacle slots: re-selection keeps boxes in their slots (their rows and duals stay put)."""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import numpy as np
import pytest

from secure3d.planning.lookback import keep_slot_positions


def _slots(*boxes_per_node):
    return np.array([[[v] * 6 for v in node] for node in boxes_per_node], dtype=float)


def test_kept_boxes_stay_in_their_slot_and_new_ones_fill_the_rest():
    previous = _slots([1, 2, 3, 4], [5, 6, 7, 8])
    selected = _slots([3, 9, 1, 2], [10, 11, 12, 13])  # node 0 reorders and swaps one box
    out = keep_slot_positions(previous, selected)
    assert out[0, :, 0].tolist() == [1, 2, 3, 9]
    assert out[1, :, 0].tolist() == [10, 11, 12, 13]  # nothing kept: the selection as it came
    for k in range(2):  # the same set of boxes per node, nothing invented or lost
        assert sorted(out[k, :, 0]) == sorted(selected[k, :, 0])


def test_duplicate_far_boxes_and_shape_changes():
    previous = _slots([1, 7, 7])
    selected = _slots([7, 7, 2])  # empty slots repeat the same far box
    out = keep_slot_positions(previous, selected)
    assert out[0, :, 0].tolist() == [2, 7, 7]
    assert keep_slot_positions(None, selected) is selected
    assert keep_slot_positions(_slots([1, 2]), selected) is selected


def test_a_solution_is_re_solved_only_if_a_left_out_box_breaks_a_row(maps_dir):
    """The slots make the NLP a relaxation: its solution needs no second solve unless a box left
    out of the slots comes closer than the margin (then the solution violates the full problem)."""
    import secure3d
    from secure3d.planning import plan_problem, problem_from_scenario
    from secure3d.planning.lookback import select_slots, slots_missing

    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    problem = problem_from_scenario(scenario)
    secure = plan_problem(problem, "secure")
    assert secure.ok, secure.message
    assignment = tuple(int(j) for j in secure.lookback)
    no_boxes = dataclasses.replace(problem, boxes_lo=np.empty((0, 3)), boxes_hi=np.empty((0, 3)))
    empty = select_slots(no_boxes, "secure", secure.states, assignment)
    # feasible for every box: nothing to re-solve for, whatever the slots hold
    for slots in (select_slots(problem, "secure", secure.states, assignment), empty):
        assert not slots_missing(problem, "secure", secure.states, assignment, slots)
    # a generous slack flags the boxes that keep their distance too
    assert slots_missing(problem, "secure", secure.states, assignment, empty, slack=1.0)
    # the baseline cuts the corner: its sight lines graze the walls the empty slots leave out
    baseline = plan_problem(problem, "baseline")
    assert slots_missing(problem, "secure", baseline.states, assignment, empty)


def test_face_gaps_bound_the_exact_distance_from_below(hull_box_pairs):
    """A box face that separates a line-of-sight hull (or an ellipsoid) from a box by g means the
    exact distance is at least g (the slot screen drops such pairs without the exact solve); the
    bound is tight where a face is the separating plane (a set straight beside the box)."""
    from types import SimpleNamespace

    from secure3d.geometry.polytope import box_pair_distances
    from secure3d.planning.lookback import FACE_GAP_TOL, _face_gaps

    n = 4000
    origins, centres, shapes, lo, hi, los = hull_box_pairs(np.random.default_rng(3), n, 0.5)
    problem = SimpleNamespace(boxes_lo=lo, boxes_hi=hi)
    idx = np.arange(n)
    gaps = _face_gaps(problem, (origins, centres, shapes, los), idx, idx)
    exact = box_pair_distances(origins, centres, shapes, lo, hi, los)
    assert np.all(gaps <= exact + FACE_GAP_TOL)
    assert np.mean(gaps > 0) > 0.5, "most random pairs are separated by a face"
    # a ball straight above a box: the top face is the separating plane, the bound is exact
    ball = (np.array([[0.5, 0.5, 3.0]]), np.array([[0.5, 0.5, 3.0]]), 0.5 * np.eye(3)[None])
    one = SimpleNamespace(boxes_lo=np.zeros((1, 3)), boxes_hi=np.ones((1, 3)))
    g = _face_gaps(one, (*ball, np.zeros(1, bool)), np.zeros(1, int), np.zeros(1, int))
    assert g[0] == pytest.approx(1.5)


def _full_slot_boxes(problem, planner, states, assignment):
    """select_slots' choice from the full screen (the matrix, row-wise argsort), as before."""
    from secure3d.planning import lookback as lb

    o = problem.options
    d = lb._hull_box_distances(problem, planner, states, assignment)
    if planner == "secure":
        d = lb._refine_distances(
            problem, states, assignment, d, lb.REFINED_PER_SLOT * o.obstacle_slots
        )
        d = lb.neighbour_minimum(d, lb.SLOT_NEIGHBOURS)
    order = np.argsort(d, axis=1)[:, : o.obstacle_slots]
    return np.where(np.take_along_axis(d, order, axis=1) <= o.obstacle_radius, order, -1)


@pytest.mark.parametrize("planner", ["secure", "baseline"])
def test_indexed_slots_and_missing_pairs_equal_the_full_screens(maps_dir, planner):
    """Through the box index, the slots (ties included: a symmetric corridor of voxel boxes puts
    boxes at equal distances from the path) and the pairs below the margin are the full screens'."""
    import secure3d
    from secure3d.planning import problem_from_scenario
    from secure3d.planning import slot_screen as ss
    from secure3d.planning.guess import initial_guess
    from secure3d.planning.lookback import (
        _hull_box_distances,
        _screened_below,
        adaptive_assignment,
        select_slots,
    )

    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / "blind_corner.yaml"))
    rng = np.random.default_rng(5)
    guess = initial_guess(problem, secure=True)
    path = np.asarray(problem.model.position(guess.states))
    # voxel boxes (0.1 m) mirrored about the path's points: equal distances on either side
    centre = path[rng.integers(0, len(path), 400)]
    offset = rng.integers(3, 12, (400, 3)) * 0.1
    offset[:, 2] = rng.integers(-5, 5, 400) * 0.1
    lo = np.round(np.concatenate([centre + offset, centre - offset - 0.1]) * 10) / 10
    lo = np.concatenate([lo, rng.integers(-20, 60, (300, 3)) * 0.1])
    hi = lo + rng.integers(1, 4, (len(lo), 3)) * 0.1
    boxes = dataclasses.replace(problem, boxes_lo=lo, boxes_hi=hi)
    assert len(lo) >= ss.INDEXED_MIN_BOXES
    for states in (guess.states, guess.states + rng.normal(0.0, 0.05, guess.states.shape)):
        assignment, _ = adaptive_assignment(boxes, states)
        slots = select_slots(boxes, planner, states, assignment)
        want = _full_slot_boxes(boxes, planner, states, assignment)
        held = want >= 0
        np.testing.assert_array_equal(slots[:, : want.shape[1], 0:3][held], lo[want[held]])
        np.testing.assert_array_equal(slots[:, : want.shape[1], 3:6][held], hi[want[held]])
        assert np.all(slots[:, : want.shape[1], 0:3][~held] > 100.0)  # empty: far away
        d = _hull_box_distances(boxes, planner, states, assignment)
        for limit in (0.02, 0.3, 1.0):
            flagged, values = _screened_below(boxes, planner, states, assignment, limit)
            assert np.array_equal(flagged, np.argwhere(d < limit))
            assert np.array_equal(values, d[d < limit])


def test_a_row_ranks_as_in_the_matrix_and_ties_are_detected():
    """The fallback for tied rows relies on numpy sorting a matrix row as it sorts the row alone;
    the tie check flags exactly the rankings a sort may break either way."""
    from secure3d.planning.slot_screen import _first, _smallest

    rng = np.random.default_rng(2)
    d = rng.integers(0, 30, (50, 3000)).astype(float) / 10  # heavy ties
    d[:, ::7] = np.inf
    order = np.argsort(d, axis=1)
    for k in range(len(d)):
        assert np.array_equal(np.argsort(d[k]), order[k])
        assert np.array_equal(_first(d[k], 8, 1.5), order[k, :8][d[k, order[k, :8]] <= 1.5])
    assert _smallest(np.array([0.3, 0.1, 0.2]), 2, 1.5, ordered=True).tolist() == [1, 2]
    assert _smallest(np.array([0.3, 0.1, 0.1]), 2, 1.5, ordered=True) is None
    assert _smallest(np.array([0.3, 0.1, 0.1]), 2, 1.5, ordered=False) is not None
    assert _smallest(np.array([0.3, 0.1, 0.3]), 2, 1.5, ordered=False) is None
    assert _smallest(np.array([2.0, 0.1, 2.0]), 2, 1.5, ordered=False).tolist() == [1]


@functools.lru_cache(maxsize=1)
def _corner_solution(maps_dir: Path):
    """blind_corner's secure plan: (problem, states, assignment, slots holding no box)."""
    import secure3d
    from secure3d.planning import plan_problem, problem_from_scenario
    from secure3d.planning.lookback import select_slots

    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / "blind_corner.yaml"))
    secure = plan_problem(problem, "secure")
    assert secure.ok, secure.message
    X, assignment = secure.states, tuple(int(j) for j in secure.lookback)
    no_boxes = dataclasses.replace(problem, boxes_lo=np.empty((0, 3)), boxes_hi=np.empty((0, 3)))
    return problem, X, assignment, select_slots(no_boxes, "secure", X, assignment)


def _left_out_distance(problem, states, assignment, empty) -> float:
    """The smallest distance (to 0.1 mm) from a box to what a node constrains, by bisection on
    ``slots_missing``'s slack with every box left out."""
    from secure3d.planning.lookback import slots_missing

    lo, hi = -problem.options.margin, 1.0
    while hi - lo > 1e-4:
        mid = 0.5 * (lo + hi)
        if slots_missing(problem, "secure", states, assignment, empty, slack=mid):
            hi = mid
        else:
            lo = mid
    return problem.options.margin + 0.5 * (lo + hi)


def test_a_left_out_box_costs_a_re_solve_only_within_part_of_the_margin(maps_dir):
    """slots_stale: a left-out box closer than the margin but farther than (1 - SLOT_TOLERANCE)
    of it keeps the solution; a closer one sends it back to the solver."""
    from secure3d.planning.lookback import (
        SLOT_TOLERANCE,
        select_slots,
        slots_missing,
        slots_stale,
    )

    problem, X, assignment, empty = _corner_solution(maps_dir)
    d = _left_out_distance(problem, X, assignment, empty)
    assert 0.0 < d < 1.0

    def with_margin(m):
        return dataclasses.replace(problem, options=dataclasses.replace(problem.options, margin=m))

    # a margin just above d: the box is within it, but not within the tolerated part of it
    between = with_margin(d / (1.0 - 0.5 * SLOT_TOLERANCE))
    assert slots_missing(between, "secure", X, assignment, empty)
    assert not slots_stale(between, "secure", X, assignment, empty)
    # a margin so large that even its reduced part reaches past d: re-solve
    beyond = with_margin(2.0 * d / (1.0 - SLOT_TOLERANCE))
    assert slots_stale(beyond, "secure", X, assignment, empty)
    # slots holding every nearby box: nothing is left out, whatever the margin
    full = select_slots(beyond, "secure", X, assignment)
    assert not slots_stale(with_margin(d), "secure", X, assignment, full)


def test_left_out_boxes_take_the_farthest_slots_nearest_first(maps_dir):
    """with_left_out_boxes: after it, a node leaves a box within the limit out only if every slot
    holds a nearer one, and the boxes it puts in are exactly the nearest left-out ones."""
    from secure3d.planning.lookback import left_out_boxes, with_left_out_boxes

    problem, X, assignment, empty = _corner_solution(maps_dir)
    limit = 1.5
    pairs, d = left_out_boxes(problem, X, assignment, empty, limit)
    assert len(pairs) > 0 and np.all(d < limit)
    S = empty.shape[1]
    filled = with_left_out_boxes(problem, X, assignment, empty, limit)
    boxes = np.concatenate([problem.boxes_lo, problem.boxes_hi], axis=1)
    for k in np.unique(pairs[:, 0]):
        mine = pairs[:, 0] == k
        nearest = pairs[mine][np.argsort(d[mine], kind="stable")][:S, 1]
        held = {tuple(b) for b in filled[k]}
        assert {tuple(boxes[j]) for j in nearest} <= held
    # what is still left out is no nearer than anything a full node holds
    rest, rest_d = left_out_boxes(problem, X, assignment, filled, limit)
    for k in np.unique(rest[:, 0]) if len(rest) else []:
        nearest_held = d[pairs[:, 0] == k]
        assert rest_d[rest[:, 0] == k].min() >= np.sort(nearest_held)[S - 1] - 1e-12
    # nothing within the limit left out: the slots come back unchanged
    assert with_left_out_boxes(problem, X, assignment, filled, 1e-3) is filled


@pytest.mark.parametrize("name", ["forest.yaml", "warehouse.yaml", "blind_corner_quadrotor.yaml"])
def test_near_views_are_the_latest_with_nearly_the_best_margin(maps_dir, name):
    """adaptive_assignment: by default each node's best view; with near_fraction, a node whose best
    view is a camera with margin to spare takes the latest earlier camera holding at least that
    fraction of the best margin (none later does), start-region nodes and nodes without margin
    keep the best; on these guesses some node's view moves (the option changes something)."""
    import secure3d
    from secure3d.errors import PlanningError
    from secure3d.planning import problem_from_scenario
    from secure3d.planning.guess import initial_guess
    from secure3d.planning.lookback import (
        NEAR_VIEW_FRACTION,
        adaptive_assignment,
        best_views,
        near_views_differ,
    )

    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / name))
    states = initial_guess(problem, secure=True).states
    best_j, best, table = best_views(problem, states)
    K, m = len(states), problem.options.margin
    first, margins = adaptive_assignment(problem, states)
    assert first == (-1, *(int(j) for j in best_j[1:]))
    assert np.array_equal(margins[1:], best[1:])
    assignment, chosen = adaptive_assignment(problem, states, NEAR_VIEW_FRACTION)
    assert assignment[0] == -1 and len(assignment) == K
    moved = 0
    for i in range(1, K):
        j = assignment[i]
        assert chosen[i] == table[i, K if j < 0 else j]
        if best_j[i] < 0 or best[i] <= m:
            assert j == best_j[i]
            continue
        limit = max(m, NEAR_VIEW_FRACTION * best[i])
        assert 0 <= j < i and table[i, j] >= limit
        assert not np.any(table[i, j + 1 : i] >= limit)
        moved += j != best_j[i]
    assert moved > 0
    assert adaptive_assignment(problem, states, 1.0)[0] == first  # ties already go to the latest
    assert near_views_differ(problem, states, NEAR_VIEW_FRACTION)
    assert not near_views_differ(problem, states, 1.0)
    for bad in (0.0, 1.5):
        with pytest.raises(PlanningError, match="near_fraction"):
            adaptive_assignment(problem, states, bad)
