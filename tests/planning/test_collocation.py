"""planning/collocation.py: the IPOPT transcription's pieces that do not need a solve."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from secure3d.dynamics import DiffDrive, PointMass, Quadrotor
from secure3d.planning.collocation import node_fractions
from secure3d.planning.kernels import model_terminal_rows


def test_only_a_wheeled_robot_needs_an_extra_rest_row_its_turn_rate():
    for model in (PointMass(), Quadrotor()):
        assert model_terminal_rows(model, ca.SX.sym("x", model.nx)) == []
    dd = DiffDrive()
    x = ca.SX.sym("x", dd.nx)
    rows = model_terminal_rows(dd, x)
    assert len(rows) == 1 and ca.is_equal(rows[0], x[4])


def test_node_fractions_are_the_node_times_over_the_final_time():
    np.testing.assert_allclose(
        node_fractions(np.array([0.0, 1.0, 3.0, 4.0]), 4), [0, 0.25, 0.75, 1]
    )


@pytest.mark.parametrize(
    "times", [[0.0, 1.0, 1.0, 2.0], [0.5, 1.0, 2.0, 3.0], [0.0, 1.0, 2.0]], ids=str
)
def test_node_fractions_refuse_times_that_do_not_rise_from_zero(times):
    with pytest.raises(ValueError, match="node times must be 4 increasing values from 0"):
        node_fractions(np.array(times), 4)
