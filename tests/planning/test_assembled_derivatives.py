"""The NLP assembled from the node kernels (an MX graph) has the rows, constraint Jacobian and
Lagrangian Hessian of the SX transcription with CasADi's whole-graph derivatives."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

import secure3d
from secure3d.planning import collocation, problem_from_scenario
from secure3d.planning.assembled_derivatives import KernelCall, assembled_nlp
from secure3d.planning.collocation import build_nlp

CASES = [
    # scenario, planner, planner options
    ("blind_corner", "secure", {"lookback_encoding": "parameter", "obstacle_slots": 3}),
    ("blind_corner", "secure", {"lookback_encoding": "structure"}),
    ("blind_corner", "baseline", {}),
    ("blind_corner", "secure", {"one_sided_duals": True, "collocation": "hermite_simpson"}),
    ("blind_corner_quadrotor", "secure", {"lookback_encoding": "parameter"}),
    ("blind_corner_quadrotor", "secure", {"interval_rows": True}),
    ("planar_blind_corner", "secure", {"lookback_encoding": "parameter"}),
]


def _whole_graph_derivatives(nlp) -> tuple[ca.Function, ca.Function]:
    w, p, f, g = (nlp.nlp[k] for k in ("x", "p", "f", "g"))
    lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", g.numel())
    hess = ca.triu(ca.hessian(lam_f * f + ca.dot(lam_g, g), w)[0])
    return (
        ca.Function("jac_ref", [w, p], [g, ca.jacobian(g, w)]),
        ca.Function("hess_ref", [w, p, lam_f, lam_g], [hess]),
    )


@pytest.mark.parametrize(("name", "planner", "options"), CASES)
def test_assembled_derivatives_equal_casadis(maps_dir, name, planner, options, monkeypatch):
    problem = problem_from_scenario(
        secure3d.load_scenario(maps_dir / f"{name}.yaml"), nodes=9, **options
    )
    K = problem.options.nodes
    # a mixed look-back: some nodes seen from earlier ones, the others in the start region
    assignment = tuple(-1 if k < 3 else k - 2 for k in range(K))
    nlp = build_nlp(problem, planner, assignment)
    assert isinstance(nlp.nlp["x"], ca.MX)
    monkeypatch.setattr(collocation, "ASSEMBLED_DERIVATIVES", False)
    reference = build_nlp(problem, planner, assignment)
    assert isinstance(reference.nlp["x"], ca.SX)
    jac_ref, hess_ref = _whole_graph_derivatives(reference)
    n_w, n_p, n_g = nlp.layout.n_w, nlp.n_p, len(nlp.lbg)
    np.testing.assert_array_equal(nlp.lbg, reference.lbg)
    rng = np.random.default_rng(3)
    for _ in range(3):
        w, p = rng.normal(size=n_w), rng.uniform(0.1, 1.0, size=n_p)
        lam_f, lam_g = rng.uniform(0.5, 2.0), rng.normal(size=n_g)
        g, J = nlp.solver_options["jac_g"](w, p)
        g_ref, J_ref = jac_ref(w, p)
        np.testing.assert_allclose(np.asarray(g).ravel(), np.asarray(nlp.g_fun(w, p)).ravel())
        np.testing.assert_allclose(np.asarray(g).ravel(), np.asarray(g_ref).ravel(), rtol=1e-12)
        H_ref, H = hess_ref(w, p, lam_f, lam_g), nlp.solver_options["hess_lag"](w, p, lam_f, lam_g)
        np.testing.assert_allclose(J.full(), J_ref.full(), rtol=1e-12, atol=1e-10)
        np.testing.assert_allclose(H.full(), H_ref.full(), rtol=1e-10, atol=1e-9)
        assert np.abs(H_ref.full()).max() > 0.0


def test_non_affine_argument_is_declined():
    """A kernel whose argument is not affine in the decision vector gets CasADi's derivatives."""
    w, p = ca.SX.sym("w", 3), ca.SX.sym("p", 1)
    x = ca.SX.sym("x")
    fn = ca.Function("k", [x], [ca.sin(x)])
    affine = KernelCall(fn, [ca.reshape(2 * w + p, 1, 3)], 3)
    assert assembled_nlp(w, p, ca.sumsqr(w), [affine], {}) is not None
    squared = KernelCall(fn, [ca.reshape(w**2, 1, 3)], 3)
    assert assembled_nlp(w, p, ca.sumsqr(w), [squared], {}) is None
