"""100 % containment of 10,000 fresh quadrotor braking manoeuvres (random attitudes up to
``max_tilt``), for the fitted family and the two-phase closed form."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.dynamics import make_model
from secure3d.reactive.controllers import BrakingController
from secure3d.reactive.family_store import family_for
from secure3d.reactive.reactive_set import check_containment, closed_form_family


@pytest.mark.parametrize("kind", ["fitted", "closed_form"])
def test_quadrotor_braking_family_contains_fresh_manoeuvres(kind):
    model = make_model("quadrotor")
    family = family_for(model, "braking", kind)
    report = check_containment(family, BrakingController(model), 10_000, np.random.default_rng(201))
    assert report.passed, str(report)
    if kind == "fitted":
        assert report.volume_ratio_vs_closed_form < 1.0


def test_quadrotor_closed_form_with_latency_and_random_held_controls():
    model = make_model("quadrotor")
    ctrl = BrakingController(model, latency=0.1)
    report = check_containment(
        closed_form_family(model, 0.1), ctrl, 1000, np.random.default_rng(202)
    )
    assert report.passed, str(report)
