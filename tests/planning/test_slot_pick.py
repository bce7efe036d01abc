"""``slot_pick="directions"``: a node's slots cover every direction before a second box of one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from secure3d.errors import ConfigError
from secure3d.planning.problem import PlannerOptions
from secure3d.planning.slot_screen import SLOT_CONE_DEG, by_direction


def _jamb_and_far_side():
    """Six touching 8 cm voxel boxes of one jamb straight ahead (+y) of the origin, 0.10-0.50 m
    away; one box on the -y side 0.40 m away, one below 0.55 m away."""
    lo = [[-0.04, 0.10 + 0.08 * i, -0.04] for i in range(6)]
    lo += [[-0.04, -0.48, -0.04], [-0.04, -0.04, -0.63]]
    lo = np.array(lo)
    hi = lo + 0.08
    d = np.linalg.norm(np.clip(0.0, lo, hi), axis=1)
    return lo, hi, np.argsort(d, kind="stable"), d


def test_by_direction_takes_the_far_side_before_more_of_the_jamb():
    lo, hi, ranked, d = _jamb_and_far_side()
    assert list(ranked[:3]) == [0, 1, 2]  # the three nearest: all on the jamb
    picked = by_direction(np.zeros(3), lo, hi, ranked, 3)
    assert list(picked) == [0, 6, 7]  # the jamb's nearest, the -y box, the box below
    assert np.all(np.diff(d[picked]) >= 0)  # in distance order
    # with room for more than the directions, the rest are the nearest of the others
    assert sorted(by_direction(np.zeros(3), lo, hi, ranked, 5)) == [0, 1, 2, 6, 7]


def test_by_direction_changes_nothing_with_room_for_every_box():
    lo, hi, ranked, _ = _jamb_and_far_side()
    assert np.array_equal(by_direction(np.zeros(3), lo, hi, ranked, len(ranked)), ranked)
    # a box holding the centre is a direction of its own; boxes within the cone wait
    lo2 = np.array([[-0.1, -0.1, -0.1], [0.2, 0.0, 0.0], [0.3, 0.01, 0.0], [-0.5, 0.0, 0.0]])
    hi2 = lo2 + 0.05
    hi2[0] = [0.1, 0.1, 0.1]
    picked = by_direction(np.zeros(3), lo2, hi2, np.arange(4), 3)
    assert list(picked) == [0, 1, 3]
    assert 0.0 < SLOT_CONE_DEG < 90.0


def test_by_direction_refuses_bad_input():
    from secure3d.errors import PlanningError

    lo, hi, ranked, _ = _jamb_and_far_side()
    with pytest.raises(PlanningError, match="centre"):
        by_direction(np.zeros(2), lo, hi, ranked, 3)
    with pytest.raises(PlanningError, match="n must"):
        by_direction(np.zeros(3), lo, hi, ranked, 0)
    with pytest.raises(PlanningError, match="ranked"):
        by_direction(np.zeros(3), lo, hi, np.array([0, 99]), 1)


def test_an_unknown_slot_pick_is_refused():
    with pytest.raises(ConfigError, match="slot_pick"):
        PlannerOptions(slot_pick="farthest")
    assert PlannerOptions().slot_pick == "nearest"


def test_directions_through_the_index_equal_the_full_screen(maps_dir):
    """Over many voxel boxes the index path and the matrix path pick the same slots by direction,
    and the default still picks the nearest."""
    import secure3d
    from secure3d.planning import lookback as lb
    from secure3d.planning import problem_from_scenario
    from secure3d.planning import slot_screen as ss
    from secure3d.planning.guess import initial_guess

    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / "blind_corner.yaml"))
    rng = np.random.default_rng(11)
    guess = initial_guess(problem, secure=True)
    path = np.asarray(problem.model.position(guess.states))
    lo = path[rng.integers(0, len(path), 600)] + rng.integers(-8, 8, (600, 3)) * 0.1
    lo = np.round(lo * 10) / 10 + 0.0125 * rng.random((600, 1))  # no ties
    hi = lo + 0.1
    many = dataclasses.replace(problem, boxes_lo=lo, boxes_hi=hi)
    assert len(lo) >= ss.INDEXED_MIN_BOXES
    assignment, _ = lb.adaptive_assignment(many, guess.states)
    S = many.options.obstacle_slots
    d = lb._hull_box_distances(many, "secure", guess.states, assignment)
    d = lb._refine_distances(many, guess.states, assignment, d, lb.REFINED_PER_SLOT * S)
    d = ss.neighbour_minimum(d, ss.SLOT_NEIGHBOURS)
    centres = lb.node_geometry(many, guess.states)["C"]
    changed = 0
    for pick, want in (
        ("nearest", ss.nearest_slots(many, d, S, None)),
        ("directions", ss.nearest_slots(many, d, S, centres)),
    ):
        opts = dataclasses.replace(many.options, slot_pick=pick)
        slots = lb.select_slots(
            dataclasses.replace(many, options=opts), "secure", guess.states, assignment
        )
        held = want >= 0
        np.testing.assert_array_equal(slots[:, :S, 0:3][held], lo[want[held]])
        if pick == "directions":
            changed = int(np.sum(np.any(want != ss.nearest_slots(many, d, S, None), axis=1)))
    assert changed > 0  # the directions changed some node's slots on this clutter


def test_a_plan_with_slots_by_direction_is_certified(maps_dir):
    """A real IPOPT plan over a mesh server map with slots by direction: certified, as fast."""
    import secure3d

    scenario = secure3d.load_scenario(maps_dir / "mesh_server.yaml")
    nearest = secure3d.plan(scenario, "secure")
    directions = secure3d.plan(scenario, "secure", slot_pick="directions")
    assert nearest.ok and directions.ok
    assert directions.certificate is not None and directions.certificate.ok
    assert directions.final_time == pytest.approx(nearest.final_time, rel=0.05)


def test_neighbour_minimum_is_the_least_over_the_nodes_either_side():
    """neighbour_minimum against a loop over the window, at its edges and for any width; bad input
    is refused by name."""
    from secure3d.errors import PlanningError
    from secure3d.planning import slot_screen as ss

    rng = np.random.default_rng(5)
    d = rng.random((7, 9))
    d[rng.random(d.shape) < 0.3] = np.inf  # unrefined entries, as select_slots writes them
    for n in (0, 1, 2, 6, 10):
        got = ss.neighbour_minimum(d, n)
        want = np.array([d[max(0, k - n) : k + n + 1].min(axis=0) for k in range(len(d))])
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(ss.neighbour_minimum(d, 0), d)
    with pytest.raises(PlanningError, match="n must be"):
        ss.neighbour_minimum(d, -1)
    with pytest.raises(PlanningError, match="shape"):
        ss.neighbour_minimum(d[0], 1)


def test_a_node_takes_its_neighbours_nearest_boxes_into_its_slots(maps_dir):
    """select_slots (secure, through the box index, on a scan): with one neighbour a node's
    slots hold boxes from its own or a neighbour's slots as they are without neighbours (the S
    nearest at their least distance over the window are among some node's own S nearest), and on
    this scan some nodes do take a neighbour's box."""
    import secure3d
    from secure3d.planning import lookback as lb
    from secure3d.planning import problem_from_scenario
    from secure3d.planning import slot_screen as ss
    from secure3d.planning.guess import initial_guess

    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / "geb079_hidden_crate.yaml"))
    assert len(problem.boxes_lo) >= ss.INDEXED_MIN_BOXES
    guess = initial_guess(problem, secure=True)
    assignment, _ = lb.adaptive_assignment(problem, guess.states)
    boxes = np.concatenate([problem.boxes_lo, problem.boxes_hi], axis=1)
    key = {tuple(b): j for j, b in enumerate(boxes)}

    def held(n):
        slots = lb.select_slots(problem, "secure", guess.states, assignment, neighbours=n)
        return [{key[tuple(b)] for b in node if tuple(b) in key} for node in slots]

    own, with_neighbours = held(0), held(1)
    assert held(ss.SLOT_NEIGHBOURS) == with_neighbours  # the default
    K = len(own)
    for k in range(K):
        window = set().union(*own[max(0, k - 1) : k + 2])
        assert with_neighbours[k] <= window, f"node {k}: a box from outside its window"
        assert len(with_neighbours[k]) == len(own[k])  # as many slots filled
    taken = [k for k in range(K) if with_neighbours[k] != own[k]]
    assert taken, "no node took a neighbour's box"
    from secure3d.errors import PlanningError

    with pytest.raises(PlanningError, match="neighbours must be"):
        lb.select_slots(problem, "secure", guess.states, assignment, neighbours=-1)
    with pytest.raises(PlanningError, match="indexed_slot_boxes: neighbours must be"):
        ss.indexed_slot_boxes(problem, "secure", None, None, None, neighbours=1.5)
