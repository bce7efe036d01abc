"""PlannerOptions.interval_rows (issue 16): node i+1's reactive set also inside node i's view."""

from __future__ import annotations

import numpy as np
import pytest

import secure3d
from secure3d.geometry.frustum import frustum_halfspaces
from secure3d.planning.problem import problem_from_scenario
from secure3d.planning.solve import plan_problem


def _support(A: np.ndarray, M: np.ndarray) -> np.ndarray:
    return np.linalg.norm(A @ M, axis=-1)


@pytest.mark.parametrize("encoding", ["structure", "parameter"])
def test_every_next_set_lies_in_the_current_nodes_view(maps_dir, encoding):
    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    problem = problem_from_scenario(
        scenario, nodes=20, interval_rows=True, lookback_encoding=encoding
    )
    plain = problem_from_scenario(scenario, nodes=20, lookback_encoding=encoding)
    from secure3d.planning.collocation import build_nlp

    a = tuple(range(-1, 19))  # any assignment: only the row count is compared
    assert len(build_nlp(problem, "secure", a).lbg) > len(build_nlp(plain, "secure", a).lbg)
    result = plan_problem(problem, "secure")
    assert result.ok and result.certificate.ok, result.message
    R, o = result.camera_rotations, result.camera_origins
    A, b = frustum_halfspaces(R, o, problem.frustum)  # (K, F, 3), (K, F)
    c, M, look = result.ellipsoid_centers, result.ellipsoid_shapes, result.lookback
    checked = 0
    for i in range(1, len(look) - 1):
        j = int(look[i])
        if j < 0:
            continue
        # E_{i+1} = {c + M z : |z| <= 1} inside node j's frustum with the margin (solver tolerance)
        slack = b[j] - A[j] @ c[i + 1] - _support(A[j], M[i + 1])
        assert slack.min() >= problem.options.margin - 1e-4, (i, j, slack.min())
        checked += 1
    assert checked >= 5


def test_a_rejection_note_names_the_node_interval_of_the_first_violation(maps_dir):
    import dataclasses

    from secure3d.planning.certificate import certify

    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    problem = problem_from_scenario(scenario, nodes=20)
    result = plan_problem(problem, "secure")
    assert result.ok and result.rejection_note() is None
    # a known box across the middle of the plan: the same plan no longer certifies
    mid = result.positions[len(result.positions) // 2]
    lo, hi = mid - 0.3, mid + 0.3
    blocked = dataclasses.replace(
        problem,
        boxes_lo=np.vstack([problem.boxes_lo, lo]),
        boxes_hi=np.vstack([problem.boxes_hi, hi]),
    )
    cert = certify(result, blocked)
    assert not cert.ok
    note = dataclasses.replace(result, rejections=(cert,)).rejection_note()
    t = cert.first_violation.time
    k = int(np.searchsorted(result.times, t, side="right") - 1)
    assert note.startswith("rejected 1 solution(s); the first: t=")
    assert f"between nodes {k} and {k + 1}" in note
