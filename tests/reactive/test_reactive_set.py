"""Reactive-set families: one body for numpy and CasADi, smooth, sound by geometry, loadable."""

from __future__ import annotations

import json
import math
import warnings

import casadi as ca
import numpy as np
import pytest

from secure3d.dynamics import make_model
from secure3d.errors import ConfigError
from secure3d.reactive._clearance import clearance
from secure3d.reactive.controllers import BrakingController
from secure3d.reactive.family_store import (
    DATA_DIR,
    FitSettings,
    cache_dir,
    family_for,
    load_family,
    load_family_file,
    save_family,
)
from secure3d.reactive.fitting import fit_family
from secure3d.reactive.reactive_set import FittedFamily, closed_form_family
from secure3d.reactive.sampling import sample_states

SHIPPED = [
    ("point_mass", "braking"),
    ("point_mass", "mpc"),
    ("quadrotor", "braking"),
    ("diff_drive", "braking"),
]


def _families():
    out = []
    for name in ("point_mass", "quadrotor", "diff_drive"):
        model = make_model(name)
        out += [closed_form_family(model), closed_form_family(model, latency=0.3)]
    for name, ctrl in SHIPPED:
        out.append(family_for(make_model(name), ctrl, "fitted"))
    return out


FAMILIES = _families()
IDS = [f"{f.model_name}-{f.controller_name}-{f.kind}-{f.latency}" for f in FAMILIES]


def test_shipped_fitted_families_exist():
    for name, ctrl in SHIPPED:
        assert (DATA_DIR / f"{name}_{ctrl}.json").is_file()
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no fallback to the closed form
            fam = family_for(make_model(name), ctrl)
        assert fam.kind == "fitted" and isinstance(fam, FittedFamily)


@pytest.mark.parametrize("family", FAMILIES, ids=IDS)
def test_casadi_and_numpy_ellipsoids_agree(family, rng):
    model = family.model
    X = sample_states(model, 40, rng)
    x = ca.SX.sym("x", model.nx)
    c_sym, M_sym = family.ellipsoid(x)
    fn = ca.Function("E", [x], [c_sym, M_sym])
    C, M = family.ellipsoid_batch(X)
    for i in range(len(X)):
        c_i, M_i = fn(X[i])
        np.testing.assert_allclose(np.array(c_i).ravel(), C[i], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.array(M_i), M[i], rtol=1e-12, atol=1e-12)
        c1, M1 = family.ellipsoid(X[i])
        np.testing.assert_allclose(c1, C[i], atol=1e-13)
        np.testing.assert_allclose(M1, M[i], atol=1e-13)
    np.testing.assert_allclose(M, np.swapaxes(M, 1, 2), atol=0, err_msg="symmetric")
    assert np.linalg.eigvalsh(M).min() > 0.5 * model.body_radius, (
        "positive definite, contains the body"
    )
    np.testing.assert_allclose(family.volume_batch(X), 4 / 3 * np.pi * np.linalg.det(M), rtol=1e-12)


@pytest.mark.parametrize("family", FAMILIES, ids=IDS)
def test_smooth_at_rest(family):
    """Finite derivatives at v = 0 (where |v| is not differentiable) and no jump near it."""
    model = family.model
    x = ca.SX.sym("x", model.nx)
    c, M = family.ellipsoid(x)
    jac = ca.Function("J", [x], [ca.jacobian(ca.vertcat(c, ca.vec(M)), x)])
    hess = ca.Function("H", [x], [ca.hessian(ca.sumsqr(ca.vertcat(c, ca.vec(M))), x)[0]])
    rest = model.rest_state((1.0, 2.0, 3.0), 0.4)
    for x0 in (rest, rest + 1e-9 * np.eye(model.nx)[3]):
        assert np.all(np.isfinite(np.array(jac(x0)))) and np.all(np.isfinite(np.array(hess(x0))))
    c0, M0 = family.ellipsoid(rest)
    c1, M1 = family.ellipsoid(rest + 1e-7 * np.eye(model.nx)[3])
    np.testing.assert_allclose(c1, c0, atol=1e-6)
    np.testing.assert_allclose(M1, M0, atol=1e-6)


@pytest.mark.parametrize("latency", [0.0, 0.3])
@pytest.mark.parametrize("norm", ["ball", "box"])
def test_point_mass_closed_form_contains_the_capsule(latency, norm, rng):
    """DESIGN.md section 4, checked geometrically (no simulation): the coasting-then-braking
    segment of length s t_d + s^2 / (2 a_b), with the body ball around every point."""
    model = make_model("point_mass", accel_norm=norm, body_radius=0.15)
    fam = closed_form_family(model, latency)
    X = sample_states(model, 500, rng)
    X[:20, 3:6] *= 1e-4  # very slow: the smoothing must not break soundness
    s = np.linalg.norm(X[:, 3:6], axis=1)
    length = s * latency + s**2 / (2 * model.limits.max_accel)
    t = np.linspace(0.0, 1.0, 101)
    vhat = X[:, 3:6] / np.maximum(s, 1e-300)[:, None]
    P = X[:, None, :3] + (length[:, None, None] * t[None, :, None]) * vhat[:, None, :]
    C, M = fam.ellipsoid_batch(X)
    cl = clearance(P.reshape(-1, 3), np.repeat(np.arange(len(X)), len(t)), C, M)
    assert cl.min() >= model.body_radius - 1e-12, cl.min() - model.body_radius


def test_fitted_is_tighter_than_closed_form_on_average(rng):
    for name, ctrl in SHIPPED:
        if ctrl != "braking":
            continue
        model = make_model(name)
        X = sample_states(model, 2000, rng)
        fitted = family_for(model, ctrl).volume_batch(X).mean()
        closed = closed_form_family(model).volume_batch(X).mean()
        assert fitted < closed, (name, fitted, closed)


def test_load_rejects_a_family_fitted_for_other_settings(tmp_path):
    path = DATA_DIR / "point_mass_braking.json"
    other = make_model("point_mass", max_accel=3.5)
    with pytest.raises(ConfigError, match=r"limits.max_accel: stored 4.0.*3.5"):
        load_family_file(path, other)
    bigger = make_model("point_mass", body_radius=0.3)
    with pytest.raises(ConfigError, match="body_radius"):
        load_family_file(path, bigger)
    smaller = make_model("point_mass", body_radius=0.1)
    assert load_family_file(path, smaller).body_radius == 0.1  # contains a smaller ball too
    with pytest.raises(ConfigError, match="latency"):
        load_family_file(path, make_model("point_mass"), latency=0.2)
    with pytest.raises(ConfigError, match="model"):
        load_family_file(path, make_model("diff_drive"))
    with pytest.raises(ConfigError, match="braking controller only"):
        load_family(make_model("point_mass"), "mpc", "closed_form")
    with pytest.raises(ConfigError, match="reactive_family"):
        load_family(make_model("point_mass"), kind="tight")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ConfigError, match="unreadable"):
        load_family_file(bad, make_model("point_mass"))


def test_quadrotor_gains_are_part_of_the_fit(tmp_path):
    data = json.loads((DATA_DIR / "quadrotor_braking.json").read_text())
    data["meta"]["controller_config"]["gains"]["attitude_gain"] = 99.0
    fake = tmp_path / "quadrotor_braking.json"
    fake.write_text(json.dumps(data))
    with pytest.raises(ConfigError, match="controller settings"):
        load_family_file(fake, make_model("quadrotor"))


def test_fit_save_load_roundtrip(tmp_path, rng):
    """A small fit contains its own sample and survives the JSON round trip bit for bit."""
    model = make_model("point_mass", max_accel=3.0, max_speed=2.0)
    ctrl = BrakingController(model)
    fam = fit_family(model, ctrl, 200, np.random.default_rng(5), n_validation=200, seed=5)
    assert fam.meta["validation_shortfall"] <= fam.meta["validation_extra_margin"]
    path = save_family(fam, tmp_path / "point_mass_braking.json")
    back = load_family_file(path, model)
    X = sample_states(model, 50, rng)
    for a, b in zip(fam.ellipsoid_batch(X), back.ellipsoid_batch(X), strict=True):
        np.testing.assert_array_equal(a, b)
    assert back.meta["seed"] == 5 and back.meta["n_samples"] == 200
    assert math.isclose(back.meta["mean_volume"], fam.meta["mean_volume"])


SMALL_FIT = FitSettings(n_samples=400, n_check=2000)


def test_limits_without_a_shipped_family_get_a_fitted_one_checked_and_cached(tmp_path, monkeypatch):
    """No fallback to the closed form: a family is fitted for the new limits, passes the
    containment check on fresh manoeuvres, is cached, and the next call reads the cache."""
    monkeypatch.setenv("SECURE3D_CACHE_DIR", str(tmp_path))
    model = make_model("point_mass", max_accel=2.5, max_speed=3.5)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fam = load_family(model, settings=SMALL_FIT, progress=False)
    assert isinstance(fam, FittedFamily)
    check = fam.meta["containment_check"]
    assert check["n_manoeuvres"] == SMALL_FIT.n_check and check["worst_excess"] < 0
    cached = list(cache_dir().glob("point_mass_braking_*.json"))
    assert cache_dir().parent == tmp_path and len(cached) == 1
    again = load_family(model, settings=SMALL_FIT, progress=False)
    assert again.meta["source"] == cached[0].name
    X = sample_states(model, 100, np.random.default_rng(3))
    for a, b in zip(fam.ellipsoid_batch(X), again.ellipsoid_batch(X), strict=True):
        np.testing.assert_array_equal(a, b)
    # Tighter than the closed form for the same limits, like the shipped families.
    assert fam.volume_batch(X).mean() < closed_form_family(model).volume_batch(X).mean()


def _shrunk_fit(model, controller, n, rng, **options):
    """A real fit whose inflation is then taken away: some manoeuvres leave its ellipsoids."""
    fam = fit_family(model, controller, n, rng, **options)
    eta = np.zeros_like(fam.eta_coef)
    eta[0] = 0.05 * model.body_radius - fam.beta_coef[0] * 0.5
    return FittedFamily(
        model,
        fam.controller_name,
        fam.latency,
        fam.feature_map,
        fam.centre_coef,
        fam.beta_coef,
        fam.gamma_coef,
        eta,
        fam.meta,
    )


def test_a_fit_that_fails_its_containment_check_is_never_used_nor_cached(tmp_path, monkeypatch):
    monkeypatch.setenv("SECURE3D_CACHE_DIR", str(tmp_path))
    model = make_model("point_mass", max_accel=2.5, max_speed=3.5)
    settings = FitSettings(n_samples=200, n_check=500, max_attempts=2)
    with pytest.raises(ConfigError, match="2 fits failed the containment check"):
        load_family(model, settings=settings, progress=False, fit=_shrunk_fit)
    assert not list(tmp_path.rglob("*.json"))


def test_fit_settings_are_validated():
    with pytest.raises(ConfigError, match="n_samples"):
        FitSettings(n_samples=10)
    with pytest.raises(ConfigError, match="margin"):
        FitSettings(margin=float("nan"))
    with pytest.raises(ConfigError, match="max_attempts"):
        FitSettings(max_attempts=True)


def test_every_shipped_scenario_flies_a_shipped_family(maps_dir, tmp_path, monkeypatch):
    """No scenario in maps/ falls back to the closed form or pays an on-demand fit."""
    from secure3d.dynamics import model_from_spec
    from secure3d.world.scenario import load_scenario

    monkeypatch.setenv("SECURE3D_CACHE_DIR", str(tmp_path))

    def refuse(*args, **kwargs):
        raise AssertionError("a shipped scenario needed an on-demand fit")

    for path in sorted(maps_dir.glob("*.yaml")):
        scenario = load_scenario(path)
        if scenario.planner.reactive_family != "fitted":
            continue
        model = model_from_spec(scenario.vehicle, scenario.camera)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            fam = load_family(model, scenario.planner.controller, fit=refuse)
        assert isinstance(fam, FittedFamily), path.name
        assert (DATA_DIR / fam.meta["source"]).is_file(), path.name
