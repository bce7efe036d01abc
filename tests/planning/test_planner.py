"""The secure planner, the baseline and the certificate on real scenarios (IPOPT solves)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import secure3d
import secure3d.errors
from secure3d.planning import PlanStatus, certify, plan, plan_problem, problem_from_scenario
from secure3d.planning.collocation import NLPCache
from secure3d.world.spec import Box, GoalSpec, StartSpec


@pytest.fixture(scope="module")
def corner(maps_dir):
    return secure3d.load_scenario(maps_dir / "blind_corner.yaml")


@pytest.fixture(scope="module")
def corner_problem(corner):
    return problem_from_scenario(corner, reactive_family="closed_form")


@pytest.fixture(scope="module")
def plans(corner_problem):
    cache = NLPCache()
    return {p: plan_problem(corner_problem, p, cache=cache) for p in ("baseline", "secure")}


def test_both_planners_succeed_and_reach_the_goal(plans, corner):
    for name, result in plans.items():
        assert result.status is PlanStatus.SUCCESS, f"{name}: {result.message}"
        np.testing.assert_allclose(
            result.positions[-1], corner.goal.position, atol=1e-4, err_msg=name
        )
        np.testing.assert_allclose(result.speeds[-1], 0.0, atol=1e-4, err_msg=name)
        np.testing.assert_allclose(result.states[0], result.states[0], err_msg=name)


def test_secure_plan_is_certified_and_baseline_is_not(plans, corner_problem):
    secure = plans["secure"]
    assert secure.certificate is not None and secure.certificate.ok, str(secure.certificate)
    baseline_cert = certify(plans["baseline"], corner_problem)
    assert not baseline_cert.ok, (
        "the baseline cuts the blind corner: its reactive sets are not observed"
    )
    assert baseline_cert.first_violation is not None
    assert 0.0 < baseline_cert.first_violation.time < plans["baseline"].final_time


def test_security_costs_time_but_not_much(plans):
    ratio = plans["secure"].final_time / plans["baseline"].final_time
    assert 1.0 < ratio < 2.5, f"secure/baseline final time {ratio:.2f}"


def test_dynamics_and_limits_hold_at_the_nodes(plans, corner_problem):
    model = corner_problem.model
    for name, r in plans.items():
        assert np.all(r.controls >= model.u_lo - 1e-6) and np.all(
            r.controls <= model.u_hi + 1e-6
        ), name
        assert np.all(r.speeds <= model.limits.max_speed + 1e-3), name
        # trapezoidal defects recomputed from the returned arrays, not from the NLP
        h = np.diff(r.times)
        F = model.f_batch(r.states, r.controls)
        defect = r.states[1:] - r.states[:-1] - 0.5 * h[:, None] * (F[:-1] + F[1:])
        assert np.abs(defect).max() < 1e-5, f"{name}: dynamics defect {np.abs(defect).max():.2e}"


def test_certificate_catches_a_plan_made_with_a_wider_camera(corner_problem):
    from secure3d.geometry.frustum import PinholeFrustum

    wide = PinholeFrustum(hfov=np.radians(160), vfov=np.radians(150), far=15.0)
    optimistic = dataclasses.replace(corner_problem, frustum=wide).with_options(certify=False)
    r = plan_problem(optimistic, "secure", cache=NLPCache())
    assert r.status is PlanStatus.SUCCESS, r.message
    cert = certify(r, corner_problem)
    assert not cert.ok, (
        "a plan relying on a field of view the camera does not have must not certify"
    )
    assert cert.min_visibility_margin < 0 <= cert.min_obstacle_margin


def test_certificate_sees_occlusion_by_a_wall_the_plan_ignored(plans, corner_problem):
    # A wall across leg 2 (floor to ceiling, a gap left on the outside): the plan's views through it
    # are blocked, so its reactive sets beyond it were never observed.
    lo = np.vstack([corner_problem.boxes_lo, [[5.5, 5.0, 0.0]]])
    hi = np.vstack([corner_problem.boxes_hi, [[7.2, 5.1, 2.5]]])
    walled = dataclasses.replace(corner_problem, boxes_lo=lo, boxes_hi=hi)
    cert = certify(plans["secure"], walled)
    assert not cert.ok
    assert cert.first_violation is not None


def test_certificate_catches_a_sped_up_plan(plans, corner_problem):
    fast = dataclasses.replace(
        plans["secure"], times=plans["secure"].times * 0.6, states=plans["secure"].states.copy()
    )
    fast.states[:, 3:6] /= 0.6  # same path, flown faster: reactive sets grow out of view
    fast.controls[:] = fast.controls / 0.36
    cert = certify(fast, corner_problem)
    assert not cert.ok


def test_fixed_lookback_also_certifies(corner_problem):
    r = plan_problem(
        corner_problem.with_options(lookback="fixed", lookback_steps=4), "secure", cache=NLPCache()
    )
    assert r.ok, r.message
    assert r.lookback_rule == "fixed"
    K = corner_problem.options.nodes
    expected = [i - 4 if i >= 4 else -1 for i in range(K)]
    assert r.lookback.tolist() == expected


def test_one_compiled_nlp_serves_every_lookback_assignment(corner_problem, plans):
    """With lookback_encoding="parameter" the assignment is a selection-matrix parameter plus row
    bounds, not structure: the fixed and the adaptive rule share one build, each plan satisfies its
    own assignment, and the plan matches the structural transcription's."""
    cache = NLPCache()
    problem = corner_problem.with_options(lookback_encoding="parameter")
    fixed = plan_problem(
        problem.with_options(lookback="fixed", lookback_steps=5), "secure", cache=cache
    )
    adaptive = plan_problem(problem, "secure", cache=cache)
    assert fixed.ok and adaptive.ok, (fixed.message, adaptive.message)
    assert fixed.lookback.tolist() != adaptive.lookback.tolist()
    assert cache.misses == 1 and len(cache) == 1
    nlp = next(iter(cache._items.values()))[0]
    for r in (fixed, adaptive):
        assert certify(r, corner_problem).ok
        view = r.lookback >= 0
        # a node's frustum rows are on exactly when it is seen from an earlier node, its
        # start-region rows exactly when it is not
        lbg, _ = nlp.bounds_for(tuple(r.lookback))
        on = np.isfinite(lbg)
        frustum_nodes = set(np.unique(nlp.row_node[on & nlp.view_rows]))
        start_nodes = set(np.unique(nlp.row_node[on & nlp.start_rows]))
        assert frustum_nodes == set(np.flatnonzero(view)) - {0}
        assert start_nodes == set(np.flatnonzero(~view)) - {0}
    np.testing.assert_allclose(adaptive.final_time, plans["secure"].final_time, rtol=0.02)


def test_an_nlp_is_compiled_ahead_when_the_assignment_is_not_structure(corner_problem):
    """``NLPCache.prepare`` (the closed loop's set-up) builds exactly the NLP the first plan then
    finds in the cache; with the assignment compiled into the structure it says so, and builds
    what every assignment's NLP shares (node kernels and their derivatives)."""
    cache = NLPCache()
    structural = corner_problem.with_options(lookback_encoding="structure")
    assert not cache.prepare(structural, "secure") and cache.misses == 1
    assert not cache.prepare(structural, "secure") and cache.misses == 1  # once per shape
    ((kernels, _, _),) = cache._kernels.values()
    derivatives = dict(kernels.derivatives)
    assert len(derivatives) >= 3  # the dynamics, the start region's and the frustum's rows
    r = plan_problem(structural, "secure", cache=cache)
    assert r.ok and r.build_time > 0.0, r.message  # its own assignment: built in the plan
    assert len(cache._kernels) == 1 and kernels.derivatives == derivatives  # nothing new shared
    parametric = corner_problem.with_options(lookback_encoding="parameter")
    misses = cache.misses
    assert cache.prepare(parametric, "secure") and cache.misses == misses + 1
    assert cache.prepare(corner_problem, "baseline") and cache.misses == misses + 2
    with pytest.raises(secure3d.errors.ConfigError, match="planner"):
        cache.prepare(corner_problem, "fastest")
    for problem, planner in ((parametric, "secure"), (corner_problem, "baseline")):
        r = plan_problem(problem, planner, cache=cache)
        assert r.ok, r.message
        assert r.build_time == 0.0
    assert cache.misses == misses + 2
    # no multipliers of the parameters are computed, so nlpsol builds no nlp_grad Function
    for nlp, _, _ in cache._items.values():
        assert not nlp.solver.has_function("nlp_grad")


def test_camera_pose_depends_on_position_and_yaw_of_a_point_mass(corner_problem):
    from secure3d.planning.kernels import camera_dims

    assert camera_dims(corner_problem.model) == (0, 1, 2, 6)


def test_warm_replan_reuses_the_compiled_nlp_and_is_faster(corner_problem, plans):
    cache = NLPCache()
    cold = plan_problem(corner_problem, "secure", cache=cache)
    misses = cache.misses
    warm = plan_problem(corner_problem, "secure", cache=cache, warm=cold)
    assert warm.ok, warm.message
    assert cache.misses == misses, "the warm replan must reuse the compiled NLP"
    assert warm.iterations < cold.iterations
    np.testing.assert_allclose(warm.final_time, cold.final_time, rtol=1e-3)
    # the warm-start solver is compiled once per NLP, and that is reported as build time
    again = plan_problem(corner_problem, "secure", cache=cache, warm=warm)
    assert again.build_time < 1e-3 and warm.build_time > 10 * again.build_time


def test_a_cold_plan_reports_the_route_its_guess_followed(corner_problem, plans):
    """route_length: the length of the cold guess's graph route through the belief, from the start
    to the goal round the corner (longer than the straight line, shorter than any detour); NaN for
    a warm replan, which starts from the earlier plan instead."""
    from secure3d.planning.guess import initial_guess

    p = corner_problem
    line = float(np.linalg.norm(p.goal - p.start_position))
    for name, result in plans.items():
        assert line * 1.05 < result.route_length < 2.0 * line, name
    route = initial_guess(p, secure=True).path
    expected = np.linalg.norm(np.diff(route, axis=0), axis=1).sum()
    assert plans["secure"].route_length == pytest.approx(expected, rel=1e-12)
    warm = plan_problem(p, "secure", cache=NLPCache(), warm=plans["secure"])
    assert warm.ok and np.isnan(warm.route_length)


def test_start_inside_an_obstacle_is_invalid_input(corner):
    with pytest.raises(secure3d.errors.ScenarioError, match="start"):
        dataclasses.replace(corner, start=StartSpec(position=(3.0, 3.0, 1.25)))
    # built past the scenario's checks (e.g. a replan from a state inside a newly seen obstacle)
    problem = problem_from_scenario(corner, reactive_family="closed_form")
    inside = problem.with_start(
        problem.model.initial_state(np.array([3.0, 3.0, 1.25]), np.zeros(3), 0.0)
    )
    r = plan_problem(inside, "secure")
    assert r.status is PlanStatus.INVALID_INPUT
    assert "start" in r.message and "inside a known obstacle" in r.message


def test_goal_walled_off_is_infeasible(corner):
    wall = Box("sealed", (5.6, 6.0, 0.0), (8.0, 6.3, 2.5))
    world = dataclasses.replace(corner.world, boxes=(*corner.world.boxes, wall))
    sealed = dataclasses.replace(corner, world=world)
    r = plan(sealed, "baseline")
    assert r.status is PlanStatus.INFEASIBLE
    assert "no collision-free path" in r.message


def test_goal_outside_the_map_is_invalid(corner):
    with pytest.raises(secure3d.errors.ScenarioError, match="goal"):
        dataclasses.replace(corner, goal=GoalSpec(position=(20.0, 1.0, 1.0)))
    problem = problem_from_scenario(corner, reactive_family="closed_form")
    outside = dataclasses.replace(problem, goal=np.array([20.0, 1.0, 1.0]))
    r = plan_problem(outside, "baseline")
    assert r.status is PlanStatus.INVALID_INPUT
    assert "outside the map" in r.message


def test_a_goal_at_the_start_is_invalid_input_for_both_planners(corner):
    """Nothing to plan, said in words (it was a ConfigError about non-finite states from the
    guess of a path of no length)."""
    problem = problem_from_scenario(corner, reactive_family="closed_form")
    here = dataclasses.replace(problem, goal=problem.start_position + 1e-8)
    for planner in ("secure", "baseline"):
        r = plan_problem(here, planner)
        assert r.status is PlanStatus.INVALID_INPUT, planner
        assert "is the start" in r.message, r.message


def test_extra_starts_keep_the_fastest_certified_plan(corner_problem, plans):
    cache = NLPCache()
    multi = plan_problem(
        corner_problem.with_options(extra_starts=[0.4, 1.0]), "secure", cache=cache
    )
    assert multi.ok and multi.certificate.ok, multi.message
    assert multi.final_time <= plans["secure"].final_time + 1e-6
    assert multi.solve_time > 0 and multi.iterations > plans["secure"].iterations
    with pytest.raises(secure3d.errors.ConfigError, match="extra_starts"):
        corner_problem.with_options(extra_starts=[0.0])
    with pytest.raises(secure3d.errors.ConfigError, match="region"):
        corner_problem.with_start(corner_problem.x0, region=(np.ones(3), np.zeros(3)))


def test_an_extra_start_from_a_guess_already_solved_is_skipped(corner_problem, plans):
    """A start whose guess is the first guess bit for bit (here the same speed fraction; on
    paper_passage_20cm 1.0 against 0.8, both capped to the same speeds) would re-solve to the
    same plan: it is not solved again. Another guess still is."""
    from secure3d.planning.solve import _solve_rounds

    def counted(calls):
        def rounds(*args, **kwargs):
            calls.append(args[2].final_time)
            return _solve_rounds(*args, **kwargs)

        return rounds

    first = corner_problem.options.guess_speed_fraction
    cache, calls = NLPCache(), []
    same = plan_problem(
        corner_problem.with_options(extra_starts=[first]),
        "secure",
        cache=cache,
        solve_rounds=counted(calls),
    )
    assert same.ok and len(calls) == 1, calls
    assert same.final_time == plans["secure"].final_time
    assert same.iterations == plans["secure"].iterations
    calls.clear()
    other = plan_problem(
        corner_problem.with_options(extra_starts=[first, 0.4]),
        "secure",
        cache=cache,
        solve_rounds=counted(calls),
    )
    assert other.ok and len(calls) == 2 and calls[1] > calls[0], calls  # 0.4: a slower guess
    assert other.iterations > plans["secure"].iterations


def test_one_sided_duals_plan_the_same_corner_and_certify(corner_problem, plans):
    problem = corner_problem.with_options(one_sided_duals=True)
    cache = NLPCache()
    for name in ("baseline", "secure"):
        result = plan_problem(problem, name, cache=cache)
        assert result.ok, f"{name}: {result.message}"
        np.testing.assert_allclose(result.final_time, plans[name].final_time, rtol=0.01)
    assert result.certificate is not None and result.certificate.ok
    nlp = next(iter(cache._items.values()))[0]
    assert nlp.layout.i_L.shape[-1] == 3  # half the separation variables
    np.testing.assert_allclose(result.warm.L[..., :3] * result.warm.L[..., 3:], 0.0)


def test_one_sided_layout_round_trip():
    from secure3d.planning.collocation import NLPLayout

    lay = NLPLayout(K=3, nx=2, nu=1, slots=2, hermite=False, one_sided=True)
    rng = np.random.default_rng(0)
    sides = rng.random((3, 2, 3)) > 0.5
    mu = rng.random((3, 2, 3))
    L6 = np.concatenate([np.where(sides, mu, 0.0), np.where(sides, 0.0, mu)], axis=-1)
    w = lay.pack(1.0, np.zeros((3, 2)), np.zeros((3, 1)), L6)
    np.testing.assert_allclose(lay.unpack(w, sides)[3], L6)
    with pytest.raises(ValueError, match="sides"):
        lay.unpack(w)


def test_one_sided_duals_option_is_validated(corner_problem):
    with pytest.raises(secure3d.errors.ConfigError, match="one_sided_duals"):
        corner_problem.with_options(one_sided_duals="yes")


def test_failed_cold_solves_fall_back_to_near_views_then_slower_guesses(corner_problem):
    """A secure cold plan whose solve fails from the first guess is retried from the same guess
    with the near views (lookback.NEAR_VIEW_FRACTION), then from slower guesses
    (``RETRY_GUESS_SPEEDS``), in turn, and the first that solves is kept."""
    from secure3d.planning import lookback as lb
    from secure3d.planning import solve as solve_mod

    real = solve_mod._solve_rounds
    calls = []

    def failing(problem, planner, guess, *args, fail=3, **kwargs):
        calls.append((guess.final_time, kwargs.get("near_fraction")))
        s, cost = real(problem, planner, guess, *args, **kwargs)
        if len(calls) <= fail:
            s = dataclasses.replace(s, status=PlanStatus.ITERATION_LIMIT)
        return s, cost

    result = plan_problem(corner_problem, "secure", cache=NLPCache(), solve_rounds=failing)
    near = lb.adaptive_assignment(corner_problem, solve_mod.initial_guess(corner_problem).states)
    assert (
        near[0]
        != lb.adaptive_assignment(
            corner_problem, solve_mod.initial_guess(corner_problem).states, lb.NEAR_VIEW_FRACTION
        )[0]
    )  # the near views differ here, so they are tried
    assert len(calls) == 2 + len(solve_mod.RETRY_GUESS_SPEEDS) == 4
    (t0, n0), (t1, n1), (t2, n2), (t3, n3) = calls
    assert n0 is None and n1 == lb.NEAR_VIEW_FRACTION and n2 is None and n3 is None
    assert t0 == t1 < t2 < t3  # the same guess, then the same path slower and slower
    assert result.ok and result.certificate.ok


def test_a_plan_longer_than_the_callers_limit_stops_before_refresh_and_certificate(corner_problem):
    """max_final_time: a solution longer than it ends the call (TOO_SLOW) after that one solve:
    no slot refresh, look-back round, slower start or certificate; a limit above the plan's
    duration changes nothing."""
    from secure3d.planning import solve as solve_mod

    cache = NLPCache()
    free = plan_problem(corner_problem, "secure", cache=cache)
    assert free.ok
    calls = []
    real = solve_mod._solve_once

    def counted(*args, **kwargs):
        calls.append(kwargs.get("left_out_limit"))
        return real(*args, **kwargs)

    solve_mod._solve_once = counted
    try:
        capped = plan_problem(
            corner_problem, "secure", cache=cache, max_final_time=0.5 * free.final_time
        )
        assert capped.status is PlanStatus.TOO_SLOW and not capped.ok
        assert calls == [None]  # the first solve only
        assert capped.certificate is None and capped.iterations > 0
        assert capped.final_time > 0.5 * free.final_time  # the refused plan, kept for the record
        assert f"over the limit of {0.5 * free.final_time:.2f} s" in capped.message
        calls.clear()
        loose = plan_problem(
            corner_problem, "secure", cache=cache, max_final_time=1.01 * free.final_time
        )
    finally:
        solve_mod._solve_once = real
    assert loose.ok and loose.final_time == pytest.approx(free.final_time, rel=1e-9)
    for bad in (0.0, -1.0, float("nan"), True, "5"):
        with pytest.raises(secure3d.errors.ConfigError, match="max_final_time"):
            plan_problem(corner_problem, "secure", cache=cache, max_final_time=bad)


def test_a_route_time_limit_is_judged_on_the_first_guesss_route(corner_problem):
    """route_time_limit: called once with the route the first guess follows (the result's
    route_length); below the plan's duration it ends the call TOO_SLOW after the first solve, as
    max_final_time does; the smaller of the two limits holds; a bad limit or return is named."""
    from secure3d.planning import solve as solve_mod

    cache = NLPCache()
    free = plan_problem(corner_problem, "secure", cache=cache)
    assert free.ok and np.isfinite(free.route_length) and free.route_length > 0
    routes = []

    def limit(route):
        routes.append(route)
        return 0.5 * free.final_time

    n_solves = []
    real = solve_mod._solve_once

    def counted(*args, **kwargs):
        n_solves.append(1)
        return real(*args, **kwargs)

    solve_mod._solve_once = counted
    try:
        capped = plan_problem(corner_problem, "secure", cache=cache, route_time_limit=limit)
    finally:
        solve_mod._solve_once = real
    assert routes == [pytest.approx(free.route_length, rel=1e-12)]
    assert capped.status is PlanStatus.TOO_SLOW and len(n_solves) == 1
    assert capped.certificate is None and capped.route_length == free.route_length
    assert f"over the limit of {0.5 * free.final_time:.2f} s" in capped.message
    loose = plan_problem(
        corner_problem, "secure", cache=cache, route_time_limit=lambda r: 10 * free.final_time
    )
    assert loose.ok and loose.final_time == pytest.approx(free.final_time, rel=1e-9)
    both = plan_problem(
        corner_problem,
        "secure",
        cache=cache,
        max_final_time=0.5 * free.final_time,
        route_time_limit=lambda r: 10 * free.final_time,
    )
    assert both.status is PlanStatus.TOO_SLOW  # the smaller limit holds
    with pytest.raises(secure3d.errors.ConfigError, match="route_time_limit: must be a function"):
        plan_problem(corner_problem, "secure", cache=cache, route_time_limit=5.0)
    for bad in (0.0, -1.0, float("nan"), "5"):
        with pytest.raises(secure3d.errors.ConfigError, match="route_time_limit: must return"):
            plan_problem(
                corner_problem, "secure", cache=cache, route_time_limit=lambda r, bad=bad: bad
            )


def test_without_slower_guesses_a_failed_first_solve_ends_the_call(corner_problem):
    """``slower_guesses=False`` (the closed loop's replans from a moving state, which brake
    instead): one start, and the call reports the first solve's failure."""
    from secure3d.planning import solve as solve_mod

    real = solve_mod._solve_rounds
    starts = []

    def failing(problem, planner, guess, *args, **kwargs):
        starts.append(guess.final_time)
        s, cost = real(problem, planner, guess, *args, **kwargs)
        return dataclasses.replace(s, status=PlanStatus.ITERATION_LIMIT), cost

    problem = corner_problem.with_options(slower_guesses=False)
    result = plan_problem(problem, "secure", cache=NLPCache(), solve_rounds=failing)
    assert len(starts) == 1 and result.status is PlanStatus.ITERATION_LIMIT
    with pytest.raises(secure3d.errors.ConfigError, match="slower_guesses: must be true or false"):
        corner_problem.with_options(slower_guesses="no")
