"""Re-certifying a plan after obstacles were added (the closed loop's shortcut) agrees with the
full certificate: whenever the shortcut passes a plan, the full certificate passes it too."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import secure3d
from secure3d.errors import PlanningError
from secure3d.geometry._box_kernels import cone_box_blocked_any
from secure3d.planning import certify, plan_problem, problem_from_scenario
from secure3d.planning.certificate import sample_plan
from secure3d.planning.collocation import NLPCache
from secure3d.planning.recertify import views_after_adding


@pytest.fixture(scope="module")
def corner(maps_dir):
    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / "blind_corner.yaml"))
    plan = plan_problem(problem, "secure", cache=NLPCache())
    assert plan.ok
    sampled = sample_plan(plan, problem)
    cert = certify(plan, problem, sampled=sampled)
    assert cert.ok
    return problem, plan, sampled, cert


def _with(problem, lo, hi):
    return dataclasses.replace(
        problem,
        boxes_lo=np.concatenate([problem.boxes_lo, lo]),
        boxes_hi=np.concatenate([problem.boxes_hi, hi]),
    )


def test_views_name_a_clear_witness_for_every_point(corner):
    problem, _, sampled, cert = corner
    views = cert.views
    assert cert.sampled is sampled
    assert views.shape == (len(sampled.points),) and np.all(views >= -1)
    seen = np.flatnonzero(views >= 0)
    assert len(seen) > 0.5 * len(views)
    assert np.all(views[seen] < sampled.owner[seen])  # an earlier camera
    blocked = cone_box_blocked_any(
        sampled.origins[views[seen]],
        sampled.points[seen],
        problem.boxes_lo,
        problem.boxes_hi,
        problem.model.body_radius,
    )
    assert not blocked.any()
    # later t_from: the points before it are not judged
    late = certify(corner[1], problem, sampled=sampled, t_from=1.0)
    before = sampled.times[sampled.owner] < 1.0 - 1e-9
    assert np.all(late.views[before] == -2) and np.all(late.views[~before] >= -1)


def test_shortcut_never_passes_what_the_certificate_fails(corner, rng):
    """Random small boxes near the manoeuvres and across the sight lines: each outcome of the
    shortcut (unchanged, some points re-searched, not shown) occurs, and a pass is always a pass of
    the full certificate against all the boxes."""
    problem, plan, sampled, cert = corner
    outcomes = {"unchanged": 0, "re-searched": 0, "not shown": 0}
    for _ in range(60):
        i = rng.integers(len(sampled.points))
        cam = sampled.origins[max(cert.views[i], 0)]
        # somewhere between the point and the camera that saw it, or near the point itself
        s = rng.uniform(0.0, 1.0)
        centre = cam + s * (sampled.points[i] - cam) + rng.normal(0.0, 0.25, 3)
        half = rng.uniform(0.02, 0.15, 3)
        lo, hi = (centre - half)[None], (centre + half)[None]
        t_from = float(rng.choice([0.0, 0.5, 1.5]))
        grown = _with(problem, lo, hi)
        views = views_after_adding(cert.views, sampled, grown, lo, hi, t_from=t_from)
        full = certify(plan, grown, sampled=sampled, t_from=t_from)
        if views is None:
            outcomes["not shown"] += 1
            continue
        assert full.ok, "the shortcut passed a plan the certificate fails"
        outcomes["unchanged" if views is cert.views else "re-searched"] += 1
        judged = sampled.times[sampled.owner] >= t_from - 1e-9
        seen = np.flatnonzero(judged & (views >= 0))
        assert not cone_box_blocked_any(
            sampled.origins[views[seen]],
            sampled.points[seen],
            grown.boxes_lo,
            grown.boxes_hi,
            problem.model.body_radius,
        ).any()
    assert all(n > 0 for n in outcomes.values()), outcomes


def test_shortcut_declines_points_it_never_judged(corner):
    problem, plan, sampled, _ = corner
    late = certify(plan, problem, sampled=sampled, t_from=2.0)
    far = np.array([[-50.0, -50.0, -50.0]])
    assert views_after_adding(late.views, sampled, problem, far, far + 0.1, t_from=2.0) is not None
    assert views_after_adding(late.views, sampled, problem, far, far + 0.1, t_from=1.0) is None
    assert views_after_adding(None, sampled, problem, far, far + 0.1) is None
    # nothing added: the views stand
    empty = np.zeros((0, 3))
    assert views_after_adding(late.views, sampled, problem, empty, empty, t_from=2.0) is late.views
    for lo, hi in ((far, far - 0.1), (far, np.zeros((2, 3))), (far[0], far[0] + 0.1)):
        with pytest.raises(PlanningError, match="added boxes"):
            views_after_adding(late.views, sampled, problem, lo, hi, t_from=2.0)


def test_a_window_before_a_known_failure_is_judged_alone(corner):
    """``t_until``: the closed loop, deferring a replan before a manoeuvre known to fail, judges
    only the part before it. A box across the plan's later half fails the whole rest; the window
    before the first failure passes, and judges only its own points; a window reaching past the
    failure fails at the same point."""
    problem, plan, sampled, _ = corner
    t = sampled.times[sampled.owner]
    late = sampled.points[t > 0.6 * plan.final_time]
    blocked = _with(problem, late.mean(axis=0)[None] - 0.3, late.mean(axis=0)[None] + 0.3)
    whole = certify(plan, blocked, sampled=sampled, t_from=0.2)
    assert not whole.ok
    bad = whole.first_violation.time
    before = certify(plan, blocked, sampled=sampled, t_from=0.2, t_until=bad)
    assert before.ok
    window = (t >= 0.2 - 1e-9) & (t < bad - 1e-9)
    assert before.n_points == window.sum() > 0
    assert np.all(before.views[~window] == -2) and np.all(before.views[window] >= -1)
    past = certify(plan, blocked, sampled=sampled, t_from=0.2, t_until=bad + 0.05)
    assert not past.ok and past.first_violation.time == bad
    assert np.array_equal(past.first_violation.point, whole.first_violation.point)


def test_a_window_must_be_numbers_in_order(corner):
    """A NaN or reversed window would judge no point and pass the plan: refused, naming it."""
    problem, plan, sampled, _ = corner
    for kw, name in (
        ({"t_from": float("nan")}, "t_from"),
        ({"t_until": float("nan")}, "t_until"),
        ({"t_from": "0"}, "t_from"),
        ({"t_until": -np.inf}, "t_until"),
        ({"t_from": 1.0, "t_until": 1.0}, "after t_from"),
    ):
        with pytest.raises(PlanningError, match=name):
            certify(plan, problem, sampled=sampled, **kw)
    assert certify(plan, problem, sampled=sampled, t_from=np.float64(0.5), t_until=np.inf).ok


def test_window_shortcut_never_passes_what_the_windowed_certificate_fails(corner, rng):
    """``t_until`` in the shortcut: the same window as the certificate's. Random boxes near the
    manoeuvres and sight lines: a pass of the shortcut is a pass of the windowed certificate, and
    boxes that only touch points after the window never stop it."""
    problem, plan, sampled, _ = corner
    t = sampled.times[sampled.owner]
    t_until = 0.5 * plan.final_time
    window = certify(plan, problem, sampled=sampled, t_from=0.2, t_until=t_until)
    assert window.ok
    shown = 0
    for _ in range(40):
        i = rng.integers(len(sampled.points))
        cam = sampled.origins[max(window.views[i], 0)]
        centre = cam + rng.uniform() * (sampled.points[i] - cam) + rng.normal(0.0, 0.25, 3)
        half = rng.uniform(0.02, 0.15, 3)
        lo, hi = (centre - half)[None], (centre + half)[None]
        grown = _with(problem, lo, hi)
        views = views_after_adding(
            window.views, sampled, grown, lo, hi, t_from=0.2, t_until=t_until
        )
        full = certify(plan, grown, sampled=sampled, t_from=0.2, t_until=t_until)
        if views is not None:
            shown += 1
            assert full.ok, "the window shortcut passed a window the certificate fails"
    assert 0 < shown < 40
    # a box on the last manoeuvre points only: outside the window, so the window still stands
    late = sampled.points[t > 0.9 * plan.final_time]
    lo, hi = late.min(axis=0)[None], late.max(axis=0)[None]
    grown = _with(problem, lo, hi)
    assert not certify(plan, grown, sampled=sampled, t_from=0.2).ok
    kept = views_after_adding(window.views, sampled, grown, lo, hi, t_from=0.2, t_until=t_until)
    assert (
        kept is not None and certify(plan, grown, sampled=sampled, t_from=0.2, t_until=t_until).ok
    )
    # the whole rest was never judged by the window's views: no shortcut for it
    assert views_after_adding(window.views, sampled, grown, lo, hi, t_from=0.2) is None
    with pytest.raises(PlanningError, match="t_until"):
        views_after_adding(window.views, sampled, grown, lo, hi, t_from=0.2, t_until=np.nan)


def test_a_deferred_window_is_judged_against_added_boxes_alone(corner, monkeypatch):
    """In flight, while a replan is deferred before a known failure, each frame re-judges the
    window before it: once a window passed, the next frame (the boxes only grew, the same failure
    time) checks only the added boxes, and a box across the window still fails it."""
    from collections import OrderedDict
    from types import SimpleNamespace

    import secure3d.planning.certificate as certificate
    from secure3d.simulation.recheck import plan_unsafe

    problem, plan, sampled, _ = corner
    calls = []
    real = certificate.certify
    monkeypatch.setattr(
        certificate, "certify", lambda *a, **k: calls.append(k.get("t_until")) or real(*a, **k)
    )
    loop = SimpleNamespace(planner="secure", rechecks=OrderedDict())
    until = 0.6 * plan.final_time
    far = np.array([[-50.0, -50.0, -50.0]])
    lo, hi = problem.boxes_lo, problem.boxes_hi
    assert plan_unsafe(loop, plan, problem, 0.1, lo, hi, until) is None
    assert calls == [until]
    lo2, hi2 = np.concatenate([lo, far]), np.concatenate([hi, far + 0.1])
    assert plan_unsafe(loop, plan, problem, 0.2, lo2, hi2, until) is None
    assert calls == [until], "the second window was judged by the certificate again"
    # a box on the window's own manoeuvres: not shown by the shortcut, failed by the certificate
    t = sampled.times[sampled.owner]
    inside = sampled.points[(t > 0.3) & (t < 0.5 * plan.final_time)]
    lo3 = np.concatenate([lo2, inside.mean(axis=0)[None] - 0.2])
    hi3 = np.concatenate([hi2, inside.mean(axis=0)[None] + 0.2])
    why = plan_unsafe(loop, plan, problem, 0.3, lo3, hi3, until)
    assert why is not None and 0.3 <= why[1] < until
    assert len(calls) == 2
