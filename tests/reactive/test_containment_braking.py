"""100 % containment of fresh braking manoeuvres: point mass and diff drive (10,000 each).

Check seeds (1xx) are independent of the fitting seeds stored in each family's metadata
(20240 + 1000 i, validation drawn from the same stream).
"""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.dynamics import make_model
from secure3d.reactive.controllers import BrakingController
from secure3d.reactive.family_store import family_for
from secure3d.reactive.reactive_set import check_containment, closed_form_family

N = 10_000


@pytest.mark.parametrize("name", ["point_mass", "diff_drive"])
@pytest.mark.parametrize("kind", ["fitted", "closed_form"])
def test_braking_family_contains_fresh_manoeuvres(name, kind):
    model = make_model(name)
    family = family_for(model, "braking", kind)
    report = check_containment(family, BrakingController(model), N, np.random.default_rng(101))
    assert report.n_manoeuvres == N and report.n_points > 50 * N
    assert report.passed, str(report)
    assert report.fraction_inside == 1.0 and report.worst_excess <= 0.0
    if kind == "fitted":
        assert report.volume_ratio_vs_closed_form < 1.0, str(report)


@pytest.mark.parametrize("norm", ["ball", "box"])
def test_point_mass_closed_form_with_latency_and_random_held_controls(norm):
    model = make_model("point_mass", accel_norm=norm)
    ctrl = BrakingController(model, latency=0.2)
    report = check_containment(
        closed_form_family(model, 0.2), ctrl, 3000, np.random.default_rng(102)
    )
    assert report.passed, str(report)


def test_diff_drive_closed_form_with_latency():
    model = make_model("diff_drive")
    ctrl = BrakingController(model, latency=0.2)
    report = check_containment(
        closed_form_family(model, 0.2), ctrl, 3000, np.random.default_rng(103)
    )
    assert report.passed, str(report)


def test_check_detects_a_family_that_is_too_small():
    """The check must be able to fail: shrink the closed form's braking length."""
    model = make_model("point_mass")
    wrong = closed_form_family(make_model("point_mass", max_accel=8.0))
    wrong.model = model
    report = check_containment(wrong, BrakingController(model), 2000, np.random.default_rng(104))
    assert not report.passed and report.worst_excess > 0.1 and report.fraction_inside < 1.0


def test_point_mass_fitted_family_with_latency():
    """A family fitted with a 0.1 s latency (random held accelerations) is picked up by latency."""
    model = make_model("point_mass")
    family = family_for(model, "braking", "fitted", latency=0.1)
    assert family.kind == "fitted" and family.latency == 0.1
    ctrl = BrakingController(model, latency=0.1)
    report = check_containment(family, ctrl, 3000, np.random.default_rng(105))
    assert report.passed and report.volume_ratio_vs_closed_form < 1.0, str(report)
