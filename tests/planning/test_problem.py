"""planning/problem.py: the Planner and Solver names and the options' checks at construction."""

from __future__ import annotations

import pytest

from secure3d.errors import ConfigError
from secure3d.planning import Planner, PlannerOptions, Solver


def test_planner_and_solver_names_compare_equal_to_their_strings():
    assert Planner.SECURE == "secure" and Planner.BASELINE == "baseline"
    assert Solver.IPOPT == "ipopt" and Solver("fatrop") is Solver.FATROP
    assert f"{Planner.SECURE}" == "secure" and str(Solver.FATROP) == "fatrop"
    assert "baseline" in tuple(Planner) and "fast" not in tuple(Planner)


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        ("nodes", 4, r"nodes: must be an integer in \[5, 400\], got 4"),
        ("nodes", True, r"nodes: must be an integer in \[5, 400\], got True"),
        ("close_gaps", -1, "close_gaps: must be an integer >= 0, got -1"),
        ("solver", "snopt", "solver: 'ipopt' or 'fatrop', got 'snopt'"),
        ("time_limit", float("nan"), "time_limit: expected a finite number"),
    ],
)
def test_options_name_the_bad_field_and_value(field, value, needle):
    with pytest.raises(ConfigError, match=needle):
        PlannerOptions(**{field: value})
