"""The stage-wise transcription for fatrop: its layout, its dynamics, the structure fatrop's
detection needs, and fatrop solves of blind_corner checked against IPOPT and the certificate."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import secure3d
from secure3d.dynamics import PointMass, Quadrotor
from secure3d.errors import ConfigError
from secure3d.planning import PlanStatus, plan, problem_from_scenario
from secure3d.planning import lookback as lb
from secure3d.planning.collocation import NLPCache, parameter_vector
from secure3d.planning.fatrop_transcription import (
    StageLayout,
    build_fatrop_nlp,
    fatrop_status,
    rk4_foh,
)
from secure3d.planning.kernels import camera_state_indices, read_indices

LOOKBACK = 4


@pytest.fixture(scope="module")
def corner(maps_dir):
    return secure3d.load_scenario(maps_dir / "blind_corner.yaml")


@pytest.fixture(scope="module")
def problem(corner):
    # the same problem as plan(corner, planner, solver="fatrop", lookback="fixed", lookback_steps=4)
    return problem_from_scenario(corner, solver="fatrop", lookback="fixed", lookback_steps=LOOKBACK)


@pytest.fixture(scope="module")
def cache():
    return NLPCache()


@pytest.fixture(scope="module")
def plans(problem, cache):
    return {p: plan(problem, p, cache=cache) for p in ("baseline", "secure")}


@pytest.fixture(scope="module")
def ipopt_plans(problem):
    ipopt = problem.with_options(solver="ipopt")
    cache = NLPCache()
    return {p: plan(ipopt, p, cache=cache) for p in ("baseline", "secure")}


@pytest.fixture(scope="module")
def nlps(problem, cache, plans):
    """The NLPs the two plans were solved with (from the cache, not rebuilt)."""
    K = problem.options.nodes
    out = {}
    for planner, assignment in (
        ("baseline", (-1,) * K),
        ("secure", lb.fixed_assignment(K, LOOKBACK)),
    ):
        out[planner], cached = cache.get(problem, planner, assignment)
        assert cached, f"the {planner} plan should have built this NLP"
    return out


# ---- layout and dynamics (no solver) -------------------------------------------------------------
@pytest.mark.parametrize("lam_stage", [None, [0, 2, 3, 4, 5, 5]])
def test_layout_is_stage_ordered_and_packs_every_copy(rng, lam_stage):
    K, nx, nu, S, D = 6, 7, 4, 2, 3
    cam = np.array([0, 1, 2, 6])
    lay = StageLayout(K=K, nx=nx, nu=nu, slots=S, depth=D, reg_idx=cam, lam_stage=lam_stage)
    hosts = np.arange(K) if lam_stage is None else np.array(lam_stage)
    blocks = [lay.i_X, lay.i_U, lay.i_Ts, lay.i_R, lay.i_Unext, lay.i_L]
    every = np.concatenate([b.ravel() for b in blocks])
    np.testing.assert_array_equal(
        np.sort(every), np.arange(lay.n_w), err_msg="indices must partition w"
    )
    for k in range(K):  # stage k = [z_k, v_k], contiguous, states first
        z = np.concatenate([lay.i_X[k], lay.i_U[k], [lay.i_Ts[k]], lay.i_R[k].ravel()])
        duals = lay.i_L[hosts == k].ravel()
        v = np.concatenate([lay.i_Unext[k] if k < K - 1 else [], duals]).astype(int)
        np.testing.assert_array_equal(np.sort(z), lay.stage_start[k] + np.arange(lay.n_z))
        np.testing.assert_array_equal(np.sort(v), lay.stage_start[k] + lay.n_z + np.arange(len(v)))
        assert lay.stage_start[k + 1] == lay.stage_start[k] + lay.n_z + len(v)

    T, X, U, L = (
        3.5,
        rng.normal(size=(K, nx)),
        rng.normal(size=(K, nu)),
        rng.uniform(size=(K, S, 6)),
    )
    w = lay.pack(T, X, U, L)
    T2, X2, U2, L2 = lay.unpack(w)
    assert T2 == T
    np.testing.assert_array_equal(X2, X)
    np.testing.assert_array_equal(U2, U)
    np.testing.assert_array_equal(L2, L)
    np.testing.assert_array_equal(w[lay.i_Ts], T)
    np.testing.assert_array_equal(w[lay.i_Unext], U[1:])
    for k in range(K):
        for m in range(D):  # r_k[m] = c(x_{k-1-m}), the start state before node 0
            np.testing.assert_array_equal(
                w[lay.i_R[k, m]], X[max(k - 1 - m, 0), cam], err_msg=f"r_{k}[{m}]"
            )


def _reference_step(model, x0, u0, u1, h):
    """Independent integration (scipy, tight tolerances) with the control linear over [0, h]."""
    sol = solve_ivp(
        lambda t, x: model.f(x, u0 + t / h * (u1 - u0)), (0.0, h), x0, rtol=1e-12, atol=1e-13
    )
    return sol.y[:, -1]


def test_rk4_foh_is_exact_for_the_point_mass_and_fourth_order_for_the_quadrotor(rng):
    pm = PointMass()
    for _ in range(5):
        x0 = pm.initial_state(rng.uniform(-2, 2, 3), rng.uniform(-3, 3, 3), rng.uniform(-3, 3))
        u0, u1 = rng.uniform(pm.u_lo, pm.u_hi), rng.uniform(pm.u_lo, pm.u_hi)
        np.testing.assert_allclose(
            rk4_foh(pm, x0, u0, u1, 0.12, steps=1),
            _reference_step(pm, x0, u0, u1, 0.12),
            atol=1e-10,
            err_msg="RK4 integrates cubic positions exactly",
        )

    quad = Quadrotor()
    errors = {1: [], 2: [], 4: []}
    for _ in range(5):
        x0 = quad.initial_state(rng.uniform(-2, 2, 3), rng.uniform(-2, 2, 3), rng.uniform(-3, 3))
        x0 = quad.step(x0, np.array([12.0, 1.5, -1.0, 0.5]), 0.3)  # tilted and rotating
        u0, u1 = rng.uniform(quad.u_lo, quad.u_hi), rng.uniform(quad.u_lo, quad.u_hi)
        ref = _reference_step(quad, x0, u0, u1, 0.12)
        for n in errors:
            errors[n].append(np.abs(rk4_foh(quad, x0, u0, u1, 0.12, steps=n) - ref).max())
    e1, e2, e4 = (max(errors[n]) for n in (1, 2, 4))
    # fourth order: the error shrinks ~16x per halving of the step (asymptotically)
    assert 8.0 < e1 / e2 < 32.0 and 8.0 < e2 / e4 < 32.0, f"errors {e1:.2e} {e2:.2e} {e4:.2e}"


def test_register_carries_exactly_what_later_rows_read(problem):
    from secure3d.planning.kernels import node_kernels

    kern, nx = node_kernels(problem), problem.model.nx
    # the point mass's camera pose is its position and yaw (secure3d.dynamics.point_mass) ...
    np.testing.assert_array_equal(camera_state_indices(kern, nx), [0, 1, 2, 6])
    # ... and the baseline's segment rows read the start node's position only
    np.testing.assert_array_equal(read_indices(kern.obs_base, 0, nx), [0, 1, 2])


def test_hermite_simpson_is_refused(problem):
    K = problem.options.nodes
    with pytest.raises(ConfigError, match="collocation"):
        build_fatrop_nlp(problem.with_options(collocation="hermite_simpson"), "baseline", (-1,) * K)


def test_adaptive_lookback_with_fatrop_stays_within_the_register_and_certifies(problem):
    """The adaptive rule with fatrop picks views at most max_span nodes back (the register depth)."""
    from secure3d.planning.problem import FATROP_MAX_SPAN

    adaptive = problem.with_options(lookback="adaptive")
    assert adaptive.options.max_span == FATROP_MAX_SPAN
    r = plan(adaptive, "secure", cache=NLPCache())
    assert r.ok, r.message
    assert r.lookback_rule == "adaptive" and r.solver == "fatrop"
    i = np.arange(len(r.lookback))
    spans = (i - r.lookback)[r.lookback >= 0]
    assert spans.min() >= 1 and spans.max() <= FATROP_MAX_SPAN
    assert r.lookback.tolist() != lb.fixed_assignment(len(i), LOOKBACK)
    assert r.certificate is not None and r.certificate.ok


def test_fatrop_status_names():
    assert fatrop_status({"fatrop": {"return_flag": 0}}) == (PlanStatus.SUCCESS, "Solve_Succeeded")
    assert fatrop_status({"fatrop": {"return_flag": 1}})[0] is PlanStatus.ITERATION_LIMIT
    assert fatrop_status({"fatrop": {"return_flag": 7}})[0] is PlanStatus.SOLVER_ERROR
    assert fatrop_status({})[0] is PlanStatus.SOLVER_ERROR


# ---- the built NLP ------------------------------------------------------------------------------
@pytest.mark.parametrize("planner", ["baseline", "secure"])
def test_nlp_has_the_structure_fatrop_detects(nlps, plans, problem, planner):
    """The rules of CasADi's structure detection (casadi/interfaces/fatrop/fatrop_interface.cpp):
    rows ordered by stage; each row touches one stage, except gap rows, which also touch exactly one
    entry of the next stage's states with coefficient +1; the Lagrangian Hessian is block-diagonal
    by stage (the interface drops anything else without a word)."""
    lay, solver = nlps[planner].layout, nlps[planner].solver
    stage = np.searchsorted(lay.stage_start, np.arange(lay.n_w), side="right") - 1
    jac = solver.get_function("nlp_jac_g")
    jsp = jac.sparsity_out(1)
    rows, cols = (np.array(a) for a in jsp.get_triplet())
    w = plans[planner].warm.w
    p = parameter_vector(problem, plans[planner].warm.slots)
    J = np.asarray(jac(w, p)[1].full())

    first = np.full(jsp.size1(), lay.K)
    np.minimum.at(first, rows, stage[cols])
    assert np.all(np.diff(first) >= 0), "constraint rows must be ordered by stage"
    n_gap = 0
    for r in range(jsp.size1()):
        c = cols[rows == r]
        later = c[stage[c] > first[r]]
        assert np.all(stage[c] <= first[r] + 1), f"row {r} spans more than two stages"
        if len(later):
            n_gap += 1
            assert len(later) == 1 and later[0] - lay.stage_start[first[r] + 1] < lay.n_z, (
                f"gap row {r}"
            )
            assert J[r, later[0]] == 1.0, f"gap row {r}: next state must enter with coefficient +1"
    assert n_gap == (lay.K - 1) * lay.n_z

    hrows, hcols = (
        np.array(a) for a in solver.get_function("nlp_hess_l").sparsity_out(1).get_triplet()
    )
    assert np.array_equal(stage[hrows], stage[hcols]), "the Lagrangian Hessian couples two stages"


def test_visibility_rows_use_the_camera_of_node_i_minus_lookback(nlps, plans, problem):
    res = plans["secure"]
    w, slots = res.warm.w, res.warm.slots
    g = np.asarray(nlps["secure"].g_fun(w, parameter_vector(problem, slots))).ravel()
    vis = g[nlps["secure"].families["visibility"]].reshape(-1, problem.frustum.n_faces)
    # independent numpy twin: margin of E_i inside the frustum of camera j (min over faces)
    margins = lb.frustum_margins(problem, lb.node_geometry(problem, res.states))
    K = problem.options.nodes
    expected = [margins[i, i - LOOKBACK] for i in range(LOOKBACK, K)]
    np.testing.assert_allclose(
        vis.min(axis=1), expected, atol=1e-9, err_msg="row of node i vs frustum of i-D"
    )


def test_baseline_rows_keep_each_segment_clear_with_its_start_nodes_duals(nlps, plans, problem):
    res = plans["baseline"]
    w, slots = res.warm.w, res.warm.slots
    g = np.asarray(nlps["baseline"].g_fun(w, parameter_vector(problem, slots))).ravel()
    rows = np.sort(g[nlps["baseline"].families["obstacle"]])
    # numpy twin: lam.(A p - b) for p_k and p_{k+1} (p_{K-1} twice at the last node), node k's duals
    P, L = res.positions, res.warm.L
    K = len(P)
    nxt = np.minimum(np.arange(K) + 1, K - 1)
    b = np.concatenate([slots[..., 3:6], -slots[..., 0:3]], axis=-1)  # (K, S, 6)

    def clearance(p):  # (K, 3) -> (K, S)
        Ap = np.concatenate([p, -p], axis=-1)[:, None, :]
        return np.einsum("ksf,ksf->ks", L, Ap - b)

    expected = np.sort(np.concatenate([clearance(P)[1:], clearance(P[nxt])[1:]], axis=None))
    np.testing.assert_allclose(rows, expected, atol=1e-9, err_msg="baseline obstacle rows")
    assert rows.min() >= problem.model.body_radius + problem.options.margin - 1e-6


# ---- fatrop solves of blind_corner --------------------------------------------------------------
def test_both_planners_succeed_with_fatrop_and_reach_the_goal(plans, corner):
    for name, r in plans.items():
        assert r.status is PlanStatus.SUCCESS, f"{name}: {r.message}"
        assert r.solver == "fatrop"
        np.testing.assert_allclose(r.positions[-1], corner.goal.position, atol=1e-4, err_msg=name)
        np.testing.assert_allclose(r.speeds[-1], 0.0, atol=1e-4, err_msg=name)


def test_secure_fatrop_plan_is_certified(plans):
    r = plans["secure"]
    assert r.certificate is not None and r.certificate.ok, str(r.certificate)
    K = len(r.times)
    assert r.lookback.tolist() == [i - LOOKBACK if i >= LOOKBACK else -1 for i in range(K)]


def test_final_times_agree_with_ipopt(plans, ipopt_plans):
    # RK4 with linear controls is exact for the point mass; IPOPT's trapezoidal collocation moves
    # the positions by up to h^2 |du| / 12 (~1 cm here) and the two solvers may stop in nearby
    # local optima: 0.02 % (baseline) and 0.3 % (secure) measured, 2 % allowed.
    for name in ("baseline", "secure"):
        assert ipopt_plans[name].ok, ipopt_plans[name].message
        np.testing.assert_allclose(
            plans[name].final_time, ipopt_plans[name].final_time, rtol=0.02, err_msg=name
        )


def test_plans_follow_the_dynamics_and_the_limits(plans, problem):
    model = problem.model
    for name, r in plans.items():
        h = np.diff(r.times)
        for k in range(len(h)):  # independent integration of the returned arrays
            x1 = _reference_step(model, r.states[k], r.controls[k], r.controls[k + 1], h[k])
            np.testing.assert_allclose(
                x1, r.states[k + 1], atol=1e-6, err_msg=f"{name}: interval {k}"
            )
        # node 0 included: u_0 acts on the first interval
        a = np.linalg.norm(r.controls[:, :3], axis=1)
        assert a.max() <= model.limits.max_accel + 1e-6, f"{name}: |a| {a.max():.4f}"
        assert r.speeds.max() <= model.limits.max_speed + 1e-6, name


def test_warm_replan_reuses_the_fatrop_nlp(problem, plans, cache):
    misses = cache.misses
    warm = plan(problem, "secure", warm=plans["secure"], cache=cache)
    assert warm.ok, warm.message
    assert cache.misses == misses, "the warm replan must reuse the compiled NLP"
    np.testing.assert_allclose(warm.final_time, plans["secure"].final_time, rtol=1e-3)


def test_iteration_limit_is_reported(problem):
    r = plan(problem.with_options(max_iter=3), "baseline", cache=NLPCache())
    assert r.status is PlanStatus.ITERATION_LIMIT, r.message
    assert r.message == "Maximum_Iterations_Exceeded"
