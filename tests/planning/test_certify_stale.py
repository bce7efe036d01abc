"""A solution whose obstacle slots are stale is certified as it is, and kept if it passes
(``planning.judging.CERTIFY_STALE``); otherwise its slots are refreshed and it is re-solved. Real
IPOPT solves and the real certificate on shipped scenes."""

from __future__ import annotations

import numpy as np
import pytest

import secure3d
from secure3d.planning import certificate as certificate_module
from secure3d.planning import judging, slot_refresh, solve
from secure3d.planning import lookback as lb
from secure3d.planning.certificate import certify
from secure3d.planning.guess import initial_guess
from secure3d.planning.problem import problem_from_scenario
from secure3d.planning.result import PlanStatus


def _recorded(monkeypatch) -> tuple[list, list]:
    """Every _solve_once (its solve) and every certificate (its verdict) of the calls that
    follow."""
    solves: list = []
    verdicts: list = []
    inner_solve, inner_certify = solve._solve_once, certificate_module.certify

    def solving(*args, **kw):
        s = inner_solve(*args, **kw)
        solves.append(s)
        return s

    def certifying(*args, **kw):
        c = inner_certify(*args, **kw)
        verdicts.append(c.ok)
        return c

    monkeypatch.setattr(solve, "_solve_once", solving)
    monkeypatch.setattr(slot_refresh, "_solve_once", solving)
    monkeypatch.setattr(certificate_module, "certify", certifying)
    return solves, verdicts


@pytest.fixture(scope="module")
def cloud_server(maps_dir):
    """cloud_server: its cold plan's first solution leaves a box 7 mm from a reactive set, inside
    half the 20 mm margin, and certifies as it is."""
    return secure3d.load_scenario(maps_dir / "cloud_server.yaml")


def test_a_stale_solution_that_certifies_is_kept_without_a_re_solve(cloud_server, monkeypatch):
    solves, verdicts = _recorded(monkeypatch)
    plan = secure3d.plan(cloud_server, "secure")
    assert plan.status is PlanStatus.SUCCESS and plan.certificate.ok
    assert len(solves) == 1  # no refresh
    assert verdicts == [True]  # certified once: the call's own verdict is the as-is one
    (first,) = solves
    problem = problem_from_scenario(cloud_server)
    margin = problem.options.margin
    # the slots were stale: a box left out of them within half the margin ...
    assert lb.slots_stale(problem, "secure", first.X, first.assignment, first.slots)
    pairs, d = lb.left_out_boxes(problem, first.X, first.assignment, first.slots, margin)
    assert len(pairs) and np.all(d > 0.0) and d.min() < 0.5 * margin
    # ... and the plan is that solution, certified anew
    assert plan.times[-1] == pytest.approx(first.T)
    assert certify(plan, problem).ok


def test_without_the_rule_the_same_scene_re_solves_to_a_plan_no_faster(cloud_server, monkeypatch):
    kept = secure3d.plan(cloud_server, "secure")
    monkeypatch.setattr(judging, "CERTIFY_STALE", False)
    solves, verdicts = _recorded(monkeypatch)
    refreshed = secure3d.plan(cloud_server, "secure")
    assert refreshed.status is PlanStatus.SUCCESS
    assert len(solves) >= 2 and verdicts == [True]
    assert refreshed.iterations > kept.iterations
    assert kept.times[-1] <= refreshed.times[-1] * (1 + 1e-3)


def test_a_stale_solution_the_certificate_refuses_is_refreshed(maps_dir, monkeypatch):
    """mesh_server's first solution runs into boxes outside its slots: the certificate refuses it
    as it is, it is re-solved with them, and the re-solved plan is certified."""
    scenario = secure3d.load_scenario(maps_dir / "mesh_server.yaml")
    solves, verdicts = _recorded(monkeypatch)
    plan = secure3d.plan(scenario, "secure")
    assert plan.status is PlanStatus.SUCCESS and plan.certificate.ok
    first = solves[0]
    problem = problem_from_scenario(scenario)
    reach = -problem.options.margin + 1e-6  # a left-out box overlaps a constrained set
    assert lb.slots_missing(problem, "secure", first.X, first.assignment, first.slots, slack=reach)
    assert len(solves) >= 2 and verdicts == [False, True]
    assert plan.times[-1] != pytest.approx(first.T, rel=1e-9)


def test_the_baseline_and_an_uncertified_call_never_take_the_shortcut(cloud_server):
    problem = problem_from_scenario(cloud_server)
    g = initial_guess(problem, secure=True)
    assignment, _ = lb.adaptive_assignment(problem, g.states)
    first = solve._solve_once(
        problem, "secure", assignment, g.final_time, g.states, g.controls, solve.DEFAULT_CACHE
    )
    assert first.status.ok
    assert judging.certified_as_is(problem, "secure", first) is not None
    assert judging.certified_as_is(problem, "baseline", first) is None
    assert judging.certified_as_is(problem.with_options(certify=False), "secure", first) is None


def test_refresh_slots_refuses_an_accept_that_is_not_callable(cloud_server):
    from secure3d.errors import PlanningError

    problem = problem_from_scenario(cloud_server)
    with pytest.raises(PlanningError, match="accept must be callable"):
        slot_refresh.refresh_slots(problem, "secure", None, solve.DEFAULT_CACHE, accept=3)
