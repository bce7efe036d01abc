"""The paper's 1D example: the reactive set is exactly the stopping interval [x, x + v|v|/2]."""

from __future__ import annotations

import numpy as np

from secure3d.reactive import one_d

DT = 0.01
#: The capped last braking step overshoots the continuous stop by at most u_max dt^2 / 8.
TOL = DT * DT / 8 + 1e-12


def _states(rng, n=200):
    x = np.stack([rng.uniform(-5, 5, n), rng.uniform(-3, 3, n)], axis=1)
    x[:5, 1] = [0.0, 1e-6, -1e-6, 3.0, -3.0]
    return x


def test_paper_law_with_obstacle_ahead_sweeps_the_stopping_interval(rng):
    x0 = _states(rng)
    ahead = x0[:, 0] + np.where(x0[:, 1] >= 0, 1, -1) * rng.uniform(0.1, 20, len(x0))
    X = one_d.rollout(x0, ahead, "paper", DT)
    np.testing.assert_allclose(X[:, -1, 1], 0.0, atol=1e-12, err_msg="every manoeuvre ends at rest")
    np.testing.assert_allclose(one_d.swept_interval(X), one_d.stopping_interval(x0), atol=TOL)
    # Independent of the simulation: the continuous stopping distance v^2 / (2 u_max).
    length = np.diff(one_d.stopping_interval(x0), axis=1)[:, 0]
    np.testing.assert_allclose(length, x0[:, 1] ** 2 / 2, atol=1e-15)


def test_reactive_set_is_the_stopping_interval(rng):
    """Union over obstacles on both sides (paper Definition 1) with the stop-always reading."""
    x0 = _states(rng, 60)
    obstacles = np.linspace(-30, 30, 13)
    np.testing.assert_allclose(
        one_d.reactive_set(x0, obstacles, "stop", DT), one_d.stopping_interval(x0), atol=TOL
    )


def test_velocity_never_reverses(rng):
    x0 = _states(rng)
    X = one_d.rollout(x0, law="stop", dt=DT)
    assert np.all(X[:, :, 1] * np.sign(x0[:, 1])[:, None] >= -1e-12), "braking overshot v = 0"


def test_paper_law_taken_literally_coasts_away_from_an_obstacle_behind():
    x0 = np.array([[0.0, 1.0], [0.0, -2.0]])
    behind = -np.sign(x0[:, 1]) * 3.0
    X = one_d.rollout(x0, behind, "paper", DT, t_max=2.0)
    np.testing.assert_allclose(
        X[:, -1, 1], x0[:, 1], err_msg="no braking: the law's 'otherwise' case"
    )
    np.testing.assert_allclose(X[:, -1, 0], 2.0 * x0[:, 1], atol=1e-9)
