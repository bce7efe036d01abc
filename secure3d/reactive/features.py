"""Smooth state features of the fitted reactive-set families (paper eq. ReactEllipse).

A fitted family is ``c(x) = p + sum_k a_k phi_k(x)`` and
``M(x) = (beta(x) + eta(x)) I + sum_d gamma_d(x) d_d(x) d_d(x)^T`` with
``beta = sum_j b_j psi_j``, ``gamma_d = sum_j G_dj psi_j``, ``eta = sum_j e_j psi_j``. The vector
features ``phi_k``, the non-negative scalar features ``psi_j`` and the directions ``d_d`` are
defined here per model. They are polynomials in the state and in smooth magnitudes
``sqrt(|v|^2 + eps^2)`` (no ``abs``/``max``/``if`` on the state), so IPOPT sees a C-infinity
constraint; with ``G, e >= 0`` and ``psi >= 0`` the shape is positive definite by construction.

Each feature map is written over components (see :mod:`secure3d.dynamics._symbolic`) so the same
body serves numpy batches and CasADi symbols.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from secure3d.errors import ConfigError

Vec = list[Any]

#: Smoothing speeds of the magnitude features (m/s, rad/s, and unitless for the tilt). Large
#: enough that the features' curvature stays moderate for IPOPT, small next to the speed range.
SPEED_EPS = 0.1
TILT_EPS = 0.05


@dataclass(frozen=True)
class Features:
    """Features of a batch of states (components: arrays of one shape, or CasADi scalars)."""

    centre: list[Vec]
    scalars: list[Any]
    directions: list[Vec]


def _point_mass(xs: list[Any], m: ModuleType) -> Features:
    v = xs[3:6]
    s = m.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + SPEED_EPS**2)
    return Features(
        centre=[v, [s * c for c in v], [s * s * c for c in v]],
        scalars=[1.0 + 0.0 * s, s, s * s],
        directions=[v],
    )


def _quadrotor(xs: list[Any], m: ModuleType) -> Features:
    v = xs[3:6]
    qw, qx, qy, qz = xs[6:10]
    # Horizontal part of the thrust axis R(q) e3: where a tilted quadrotor is being pushed.
    w = [2 * (qx * qz + qw * qy), 2 * (qy * qz - qw * qx), 0.0 * qw]
    tilt2 = w[0] * w[0] + w[1] * w[1]
    s = m.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + SPEED_EPS**2)
    n = m.sqrt(tilt2 + TILT_EPS**2)
    vw = v[0] * w[0] + v[1] * w[1]
    one = 1.0 + 0.0 * s
    zero = 0.0 * s
    e3 = [zero, zero, one]
    return Features(
        centre=[
            v,
            [s * c for c in v],
            [s * s * c for c in v],
            [vw * c for c in v],
            w,
            [s * c for c in w],
            [vw * c for c in w],
            e3,
            [s * c for c in e3],
            [v[2] * c for c in e3],
            [tilt2 * c for c in e3],
            [vw * c for c in e3],
        ],
        scalars=[one, s, s * s, n, s * n, tilt2],
        directions=[v, w, e3],
    )


def _diff_drive(xs: list[Any], m: ModuleType) -> Features:
    th, v, om = xs[2], xs[3], xs[4]
    c, sn = m.cos(th), m.sin(th)
    zero = 0.0 * c
    h = [c, sn, zero]
    lat = [-sn, c, zero]
    sv = m.sqrt(v * v + SPEED_EPS**2)
    sw = m.sqrt(om * om + SPEED_EPS**2)
    one = 1.0 + zero
    return Features(
        centre=[
            [v * e for e in h],
            [v * sv * e for e in h],
            [v * sw * e for e in h],
            [v * sv * sw * e for e in h],
            [v * om * e for e in lat],
            [v * sv * om * e for e in lat],
            [v * om * sw * e for e in lat],
            [v * sv * om * sw * e for e in lat],
        ],
        scalars=[one, sv, sv * sv, sw, sv * sw, sv * sv * sw, sw * sw],
        directions=[h, lat],
    )


FEATURE_MAPS = {
    "point_mass/v1": _point_mass,
    "quadrotor/v1": _quadrotor,
    "diff_drive/v1": _diff_drive,
}


def features(name: str, xs: list[Any], m: ModuleType) -> Features:
    """Evaluate the feature map ``name`` on state components ``xs`` with math namespace ``m``."""
    try:
        fn = FEATURE_MAPS[name]
    except KeyError:
        raise ConfigError(f"reactive family features: unknown map {name!r}") from None
    return fn(xs, m)


def sizes(name: str, nx: int) -> tuple[int, int, int]:
    """(number of centre features K, scalar features J, directions D) of the map ``name``."""
    f = features(name, [np.zeros(1) for _ in range(nx)], np)
    return len(f.centre), len(f.scalars), len(f.directions)
