"""The certificate's chunked pass (planning/certificate.py)."""

from __future__ import annotations

import dataclasses


def test_certifying_in_chunks_gives_the_answers_of_one_pass(monkeypatch, maps_dir):
    """The certificate judges manoeuvre points CHUNK_POINTS at a time (so that a plan call's
    budget can stop it): every margin, view and violation equals one pass over all points."""
    import numpy as np

    import secure3d
    from secure3d.planning import certificate
    from secure3d.planning.problem import problem_from_scenario

    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    plan = secure3d.plan(scenario, "secure", certify=False)
    problem = problem_from_scenario(scenario)
    # a problem whose start box is small, so that most points need a view and some fail
    tight = dataclasses.replace(
        problem, start_region_lo=problem.x0[:3] - 0.3, start_region_hi=problem.x0[:3] + 0.3
    )
    for judged in (problem, tight):
        monkeypatch.setattr(certificate, "CHUNK_POINTS", 10**9)
        whole = certificate.certify(plan, judged)
        monkeypatch.setattr(certificate, "CHUNK_POINTS", 97)
        chunked = certificate.certify(plan, judged, sampled=whole.sampled)
        assert whole.n_points > 10 * 97
        for name in ("ok", "min_margin", "min_visibility_margin", "min_obstacle_margin"):
            assert getattr(chunked, name) == getattr(whole, name), name
        np.testing.assert_array_equal(chunked.views, whole.views)
        assert repr(chunked.first_violation) == repr(whole.first_violation)


def test_frames_taken_before_the_plan_count_as_earlier_views(maps_dir):
    """A replan's certificate counts the frames the camera took before it (``past_views``) as
    views earlier than every plan point: with a start box too small for the first manoeuvres the
    plan fails, a frame from behind the start that sees them makes it pass, and a frame that
    looks away does not. The views record PAST_VIEW for the points it observed."""
    import numpy as np
    import pytest

    import secure3d
    from secure3d.errors import ConfigError
    from secure3d.planning import certificate, recertify
    from secure3d.planning.problem import problem_from_scenario

    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    plan = secure3d.plan(scenario, "secure", certify=False)
    problem = problem_from_scenario(scenario)
    p0 = problem.x0[:3]
    tight = dataclasses.replace(problem, start_region_lo=p0 - 0.25, start_region_hi=p0 + 0.25)
    failed = certificate.certify(plan, tight)
    assert not failed.ok and failed.first_violation.time < 0.5
    heading = plan.states[3][:3] - p0  # where the plan sets off
    heading[2] = 0.0
    heading /= np.linalg.norm(heading)
    behind = p0 - 0.8 * heading  # in the room, before its west wall

    def looking(d: np.ndarray) -> np.ndarray:  # camera (x right, y down, z forward) to world
        z = d / np.linalg.norm(d)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        return np.stack([x, np.cross(z, x), z], axis=1)

    seen = dataclasses.replace(tight, past_views=(looking(heading)[None], behind[None]))
    cert = certificate.certify(plan, seen, sampled=failed.sampled)
    early = failed.sampled.times[failed.sampled.owner] < failed.first_violation.time + 0.1
    assert np.any(cert.views[early] == certificate.PAST_VIEW)
    assert cert.first_violation is None or cert.first_violation.time > failed.first_violation.time
    # re-certified after boxes join the map: a box far away keeps every view, the past frame's
    # too (the shortcut, no full certificate); a box in the frame's line of sight does not
    assert cert.ok

    def plus(lo: np.ndarray, hi: np.ndarray) -> object:
        boxes = (np.vstack([seen.boxes_lo, lo]), np.vstack([seen.boxes_hi, hi]))
        return dataclasses.replace(seen, boxes_lo=boxes[0], boxes_hi=boxes[1])

    far = (np.array([[7.0, 7.0, 0.1]]), np.array([[7.1, 7.1, 0.2]]))
    kept = recertify.views_after_adding(cert.views, cert.sampled, plus(*far), *far)
    np.testing.assert_array_equal(kept, cert.views)
    mid = behind + 0.4 * heading
    block = ((mid - 0.02)[None], (mid + 0.02)[None])
    assert recertify.views_after_adding(cert.views, cert.sampled, plus(*block), *block) is None
    assert not certificate.certify(plan, plus(*block), sampled=cert.sampled).ok
    away = dataclasses.replace(tight, past_views=(looking(-heading)[None], behind[None]))
    again = certificate.certify(plan, away, sampled=failed.sampled)
    assert repr(again.first_violation) == repr(failed.first_violation)
    assert not np.any(again.views == certificate.PAST_VIEW)
    with pytest.raises(ConfigError, match="past_views"):
        dataclasses.replace(tight, past_views=(np.zeros((2, 3, 3)), np.zeros((1, 3))))
    with pytest.raises(ConfigError, match="proper rotations"):
        dataclasses.replace(tight, past_views=(2.0 * looking(heading)[None], behind[None]))


def test_first_only_names_the_violation_of_a_full_pass(monkeypatch, maps_dir):
    """``certify(first_only=True)`` (the in-flight re-check) stops after the first failing sample,
    in chunks of FIRST_CHUNK_POINTS: on passing and failing plans (unseen points, an obstacle on
    the way, both), from several start times and chunk sizes, its verdict and violation equal a
    full pass's, and a pass's margins and views are the full pass's too."""
    import numpy as np

    import secure3d
    from secure3d.planning import certificate
    from secure3d.planning.problem import problem_from_scenario

    scenario = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    plan = secure3d.plan(scenario, "secure", certify=False)
    problem = problem_from_scenario(scenario)
    p0 = problem.x0[:3]
    tight = dataclasses.replace(problem, start_region_lo=p0 - 0.3, start_region_hi=p0 + 0.3)
    mid = plan.states[len(plan.states) // 2][:3]  # a box on the way, half-way along the plan
    blocked = {}
    for name, judged in (("open", problem), ("tight", tight)):
        lo, hi = np.vstack([judged.boxes_lo, mid - 0.05]), np.vstack([judged.boxes_hi, mid + 0.05])
        blocked[name] = dataclasses.replace(judged, boxes_lo=lo, boxes_hi=hi)
    outcomes, stopped = set(), 0
    for judged in (problem, tight, blocked["open"], blocked["tight"]):
        whole = certificate.certify(plan, judged)
        for t_from in (0.0, 0.37, 1.5, 3.0):
            full = certificate.certify(plan, judged, t_from=t_from, sampled=whole.sampled)
            for chunk in (37, 512, 10**6):
                monkeypatch.setattr(certificate, "FIRST_CHUNK_POINTS", chunk)
                first = certificate.certify(
                    plan, judged, t_from=t_from, sampled=whole.sampled, first_only=True
                )
                assert first.ok == full.ok
                assert repr(first.first_violation) == repr(full.first_violation)
                if full.ok:
                    np.testing.assert_array_equal(first.views, full.views)
                    assert first.min_margin == full.min_margin
                else:
                    assert first.n_points <= full.n_points
                    stopped += first.n_points < full.n_points
                    assert first.min_margin <= full.first_violation.margin
            v = full.first_violation
            outcomes.add("pass" if v is None else v.reason.split(" ")[0])
    # the cases cover a pass, an obstacle hit and an unseen point
    assert {"pass", "reactive", "manoeuvre"} <= outcomes, outcomes
    assert stopped > 0  # and some failing passes stopped before the end
