"""Obstacle slots: re-selection keeps boxes in their slots (their rows and duals stay put)."""

from __future__ import annotations

import numpy as np

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
