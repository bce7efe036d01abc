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
