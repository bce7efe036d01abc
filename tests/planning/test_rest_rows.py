"""The terminal rest rows: the velocity's components, or fewer well-conditioned state rows."""

from __future__ import annotations

import casadi as ca
import numpy as np

import secure3d
from secure3d.planning.constraints import rest_rows
from secure3d.planning.problem import problem_from_scenario


def _model(maps_dir, name):
    return problem_from_scenario(secure3d.load_scenario(maps_dir / f"{name}.yaml")).model


def test_the_diff_drive_rests_when_its_signed_speed_is_zero(maps_dir):
    model = _model(maps_dir, "planar_blind_corner")
    x = ca.SX.sym("x", model.nx)
    rows = ca.vertcat(*rest_rows(model, x))
    assert rows.numel() == 1
    # one row, full rank everywhere: the velocity is zero exactly when it is
    rng = np.random.default_rng(0)
    vel = ca.vertcat(*[model.velocity(x)[d] for d in range(3)])
    f = ca.Function("f", [x], [rows, vel, ca.jacobian(rows, x)])
    for _ in range(5):
        xv = rng.normal(size=model.nx)
        xv[3] = 0.0
        r, vel, J = (np.asarray(a, dtype=float) for a in f(xv))
        np.testing.assert_allclose(r, 0.0, atol=0.0)
        np.testing.assert_allclose(vel, 0.0, atol=0.0)
        assert np.linalg.matrix_rank(J) == 1


def test_point_masses_and_quadrotors_keep_their_velocity_rows(maps_dir):
    for name in ("blind_corner", "blind_corner_quadrotor"):
        model = _model(maps_dir, name)
        x = ca.SX.sym("x", model.nx)
        rows = rest_rows(model, x)
        vel = model.velocity(x)
        assert len(rows) == 3
        for d in range(3):
            assert ca.is_equal(rows[d], vel[d], 2), name
