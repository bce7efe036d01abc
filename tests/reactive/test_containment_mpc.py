"""100 % containment of fresh MPC manoeuvres (random states and random obstacles)."""

from __future__ import annotations

import numpy as np
import pytest

from secure3d.dynamics import make_model
from secure3d.reactive.controllers import MPCReactiveController
from secure3d.reactive.family_store import family_for
from secure3d.reactive.reactive_set import check_containment


def _check(n, seed):
    model = make_model("point_mass")
    family = family_for(model, "mpc")
    return check_containment(family, MPCReactiveController(model), n, np.random.default_rng(seed))


def test_mpc_family_contains_fresh_manoeuvres_fast():
    report = _check(2000, 301)
    assert report.passed, str(report)


@pytest.mark.slow
def test_mpc_family_contains_10000_fresh_manoeuvres():
    report = _check(10_000, 302)
    assert report.passed, str(report)
