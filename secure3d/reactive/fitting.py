"""Fit tight reactive-set families to simulated manoeuvres (paper section "The reactive set").

The paper bounds simulated reactive trajectories with ellipsoids and lets Q and a vary with the
state. We fit the smooth family of :mod:`secure3d.reactive.features` in four steps:

1. Simulate the controller from ``n_samples`` random states (random held controls during the
   latency, random obstacles for the MPC) and keep every integration step's position.
2. Per manoeuvre, the minimum-volume ellipsoid (Khachiyan's algorithm, multiplicative form) of the
   body balls (each point plus 14 directions at the body radius, on a subsample of the points).
3. Least squares: centre coefficients to the per-manoeuvre centres, shape coefficients (>= 0, so
   the shape stays positive definite) to the per-manoeuvre shapes.
4. Inflation: for each manoeuvre the exact smallest isotropic inflation ``eta_i`` with every body
   ball of every point inside (:func:`secure3d.reactive._clearance.required_inflation`); then a
   linear program picks ``eta(x) = e . psi(x) >= eta_i + margin`` minimising the first-order change
   of the mean volume. A validation sample drawn after the fitting sample raises the margin (by
   twice its shortfall) if some of its manoeuvres are not contained.

Containment on fresh manoeuvres is then *checked*, not assumed (:func:`check_containment`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.optimize import linprog, lsq_linear

from secure3d.dynamics import _symbolic as sym
from secure3d.dynamics.base import VehicleModel
from secure3d.errors import ConfigError
from secure3d.reactive import _clearance
from secure3d.reactive import features as feat
from secure3d.reactive.reactive_set import FittedFamily, closed_form_family, manoeuvre_points
from secure3d.reactive.sampling import sample_hold_controls, sample_obstacles, sample_states

#: Unit directions (6 axes, 8 diagonals) approximating the body ball for the minimum-volume fit.
_BALL_DIRS = np.concatenate(
    [
        np.vstack([np.eye(3), -np.eye(3)]),
        np.array(np.meshgrid(*[[-1, 1]] * 3)).reshape(3, -1).T / np.sqrt(3),
    ]
)


def mvee(points: np.ndarray, iterations: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-volume enclosing ellipsoids of batches of points (approximate).

    Multiplicative Khachiyan/Titterington update of the design weights, vectorised over the batch.

    Parameters
    ----------
    points : (B, n, 3) float.
    iterations : number of weight updates.

    Returns
    -------
    centres : (B, 3) float.
    shapes : (B, 3, 3) float, M with E = {c + M z : |z| <= 1} (slightly too small until converged;
        the inflation step of the fit makes up for it).
    """
    B, n, d = points.shape
    Q = np.concatenate([points, np.ones((B, n, 1))], axis=2)
    u = np.full((B, n), 1.0 / n)
    for _ in range(iterations):
        X = np.matmul(np.swapaxes(Q * u[:, :, None], 1, 2), Q)
        g = np.sum(np.matmul(Q, np.linalg.inv(X)) * Q, axis=2)
        u *= g / (d + 1)
        u /= u.sum(axis=1, keepdims=True)
    c = np.einsum("bn,bni->bi", u, points)
    cov = np.einsum("bn,bni,bnj->bij", u, points, points) - np.einsum("bi,bj->bij", c, c)
    # The MVEE is {y : (y - c)' (d cov)^-1 (y - c) <= 1}: M = sqrt(d cov). Scale so the points fit.
    w, V = np.linalg.eigh(d * cov)
    w = np.maximum(w, 1e-12)
    M = np.einsum("bij,bj,bkj->bik", V, np.sqrt(w), V)
    Minv = np.einsum("bij,bj,bkj->bik", V, 1 / np.sqrt(w), V)
    rad = np.linalg.norm(np.einsum("bij,bnj->bni", Minv, points - c[:, None]), axis=2).max(axis=1)
    return c, M * rad[:, None, None]


def _ball_clouds(
    points: np.ndarray, offsets: np.ndarray, radius: float, per_manoeuvre: int
) -> np.ndarray:
    """(B, per_manoeuvre * 14, 3): subsampled manoeuvre points, each spread over its body ball."""
    counts = np.diff(offsets)
    frac = np.linspace(0.0, 1.0, per_manoeuvre)
    idx = offsets[:-1, None] + np.round(frac[None, :] * (counts[:, None] - 1)).astype(int)
    centres = points[idx]  # (B, m, 3)
    return (centres[:, :, None, :] + radius * _BALL_DIRS[None, None]).reshape(len(counts), -1, 3)


def _feature_arrays(
    name: str, model: VehicleModel, X: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre features (N, K, 3), scalar features (N, J), directions (N, D, 3) of states X."""
    f = feat.features(name, sym.split(X, model.nx, "X"), np)
    n = len(X)

    def vecs(vs: list[list[Any]]) -> np.ndarray:
        return np.stack(
            [
                np.stack(np.broadcast_arrays(*[np.broadcast_to(c, (n,)) for c in v]), axis=1)
                for v in vs
            ],
            axis=1,
        )

    scal = np.stack([np.broadcast_to(s, (n,)) for s in f.scalars], axis=1)
    return vecs(f.centre), scal, vecs(f.directions)


_SYM6 = ([0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2])
_W6 = np.array([1, 1, 1, np.sqrt(2), np.sqrt(2), np.sqrt(2)])


def _fit_shape(
    scal: np.ndarray, dirs: np.ndarray, M_target: np.ndarray, beta_min: float
) -> tuple[np.ndarray, np.ndarray]:
    """Non-negative least squares of M ~ (b . psi) I + sum_d (G_d . psi) d d^T (Frobenius norm)."""
    n, J = scal.shape
    D = dirs.shape[1]
    i, j = _SYM6
    eye6 = np.eye(3)[i, j] * _W6
    cols = [scal[:, k, None] * eye6[None, :] for k in range(J)]
    for d in range(D):
        dd = dirs[:, d, i] * dirs[:, d, j] * _W6
        cols += [scal[:, k, None] * dd for k in range(J)]
    A = np.stack([c.reshape(-1) for c in cols], axis=1)
    y = (M_target[:, i, j] * _W6).reshape(-1)
    lb = np.zeros(A.shape[1])
    lb[0] = beta_min
    sol = lsq_linear(A, y, bounds=(lb, np.inf), lsmr_tol="auto", max_iter=2000)
    return sol.x[:J], sol.x[J:].reshape(D, J)


def _envelope(scal: np.ndarray, need: np.ndarray, weight: np.ndarray, floor: float) -> np.ndarray:
    """LP: min sum_i w_i (e . psi_i) s.t. e . psi_i >= need_i, e_j >= 0 for j >= 1, e_0 >= floor."""
    c = (weight[:, None] * scal).sum(axis=0)
    bounds = [(floor, None)] + [(0.0, None)] * (scal.shape[1] - 1)
    res = linprog(c / np.abs(c).max(), A_ub=-scal, b_ub=-need, bounds=bounds, method="highs")
    if res.status != 0:
        raise ConfigError(f"fit_family: inflation LP failed ({res.message})")
    # HiGHS meets constraints to ~1e-9; never let that round a required inflation down.
    return res.x + np.r_[max(0.0, float((need - scal @ res.x).max())), np.zeros(scal.shape[1] - 1)]


def _simulate(
    controller: Any, X: np.ndarray, rng: np.random.Generator, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    model = controller.model
    u_hold = sample_hold_controls(model, len(X), rng) if controller.latency > 0 else None
    context = {}
    if controller.name == "mpc":
        lo, hi = sample_obstacles(model, X, rng)
        context = {"obstacle_lo": lo, "obstacle_hi": hi}
    return manoeuvre_points(controller, X, dt, u_hold, **context)


def _inflation(
    base: FittedFamily,
    X: np.ndarray,
    scal: np.ndarray,
    pts: np.ndarray,
    off: np.ndarray,
    margin: float,
    floor: float,
) -> np.ndarray:
    """The inflation coefficients eta: the envelope of what each fitting manoeuvre needs (plus
    ``margin``) over the uninflated family ``base``, weighted by d(volume)/d(eta)."""
    r = base.model.body_radius
    C, M = base.ellipsoid_batch(X)
    need = _clearance.required_inflation(pts, off, C, M, r)
    # d(volume)/d(eta) of each ellipsoid: the sum of pairwise products of its semi-axes.
    ev = np.linalg.eigvalsh(M)
    weight = ev[:, 0] * ev[:, 1] + ev[:, 0] * ev[:, 2] + ev[:, 1] * ev[:, 2]
    return _envelope(scal, need + margin, weight, floor)


def _volumes(fam: FittedFamily, model: VehicleModel, latency: float, X: np.ndarray) -> dict:
    """Mean volume of ``fam``'s sets over ``X``, against the closed-form family's."""
    vol = fam.volume_batch(X).mean()
    vol_cf = closed_form_family(model, latency).volume_batch(X).mean()
    return {
        "mean_volume": float(vol),
        "mean_volume_closed_form": float(vol_cf),
        "volume_ratio": float(vol / vol_cf),
    }


def _fit_sample(
    controller: Any,
    name: str,
    n_samples: int,
    rng: np.random.Generator,
    dt: float,
    margin: float,
    points_per_manoeuvre: int,
    step: Callable[[str], None],
) -> tuple[FittedFamily, np.ndarray]:
    """Fit the family on ``n_samples`` manoeuvres drawn from ``rng``: their minimum-volume
    ellipsoids, the centre and shape coefficients, then the inflation that covers every point.

    Returns
    -------
    The family without inflation (``eta`` zero) and the inflation coefficients ``eta`` (J,).
    """
    model = controller.model
    r = model.body_radius
    X = sample_states(model, n_samples, rng)
    pts, off = _simulate(controller, X, rng, dt)
    step("simulate")
    clouds = _ball_clouds(pts, off, r, points_per_manoeuvre)
    c_t, M_t = mvee(clouds)
    step("ellipsoids")

    cen, scal, dirs = _feature_arrays(name, model, X)
    p = model.position(X)
    a, *_ = np.linalg.lstsq(
        cen.transpose(0, 2, 1).reshape(-1, cen.shape[1]), (c_t - p).reshape(-1), rcond=None
    )
    beta, gamma = _fit_shape(scal, dirs, M_t, beta_min=0.5 * r)
    step("shapes")

    zeros = np.zeros(scal.shape[1])
    base = FittedFamily(model, controller.name, controller.latency, name, a, beta, gamma, zeros)
    eta = _inflation(base, X, scal, pts, off, margin, floor=-beta[0] + 0.25 * r)
    step("inflation")
    return base, eta


@dataclass(frozen=True)
class _Validation:
    """A fit checked on fresh manoeuvres: the validation ``states`` (n, nx), the largest
    ``shortfall`` (m) of the fitted inflation below the one they need, the ``extra`` inflation
    (m) added for it, and the inflation coefficients ``eta`` with it."""

    states: np.ndarray
    shortfall: float
    extra: float
    eta: np.ndarray


def _validate(
    base: FittedFamily,
    controller: Any,
    eta: np.ndarray,
    n_val: int,
    rng: np.random.Generator,
    dt: float,
) -> _Validation:
    """Check the fitted inflation ``eta`` of ``base`` on ``n_val`` fresh manoeuvres (drawn from
    ``rng``) and raise it where they need more."""
    model = base.model
    Xv = sample_states(model, n_val, rng)
    pv, ov = _simulate(controller, Xv, rng, dt)
    _, scal_v, _ = _feature_arrays(base.feature_map, model, Xv)
    Cv, Mv = base.ellipsoid_batch(Xv)
    need_v = _clearance.required_inflation(pv, ov, Cv, Mv, model.body_radius)
    shortfall = float((need_v - scal_v @ eta).max())
    extra = 0.0
    if shortfall > 0:
        # psi_0 = 1, so raising e_0 raises eta everywhere: by twice what the validation lacked.
        extra = 2.0 * shortfall
        eta = eta + np.r_[extra, np.zeros(len(eta) - 1)]
    return _Validation(Xv, shortfall, extra, eta)


def fit_family(
    model: VehicleModel,
    controller: Any,
    n_samples: int,
    rng: np.random.Generator,
    *,
    n_validation: int | None = None,
    dt: float = 0.01,
    margin: float = 0.01,
    points_per_manoeuvre: int = 16,
    feature_map: str | None = None,
    seed: int | None = None,
    progress: Callable[[str], None] | None = None,
) -> FittedFamily:
    """Fit a reactive-set family of ``controller``'s manoeuvres (see module docstring).

    Parameters
    ----------
    model : the vehicle (limits and body radius are stored with the fit).
    controller : BrakingController or MPCReactiveController of ``model``.
    n_samples : fitting manoeuvres.
    rng : generator; the fitting sample is drawn first, then the validation sample.
    n_validation : validation manoeuvres (default ``n_samples``).
    dt : integration step (s).
    margin : isotropic safety inflation (m) on top of the largest required inflation.
    points_per_manoeuvre : points per manoeuvre used by the minimum-volume step (the inflation
        step uses all of them).
    feature_map : feature map name (default per model).
    seed : recorded in the family's metadata (the seed that made ``rng``).
    progress : called with a stage name after each of the fit's six stages (a progress bar).

    Returns
    -------
    FittedFamily whose ``meta`` records the settings, the validation outcome and mean volumes.
    """
    if controller.model is not model:
        raise ConfigError("fit_family: the controller must be built on the same model")
    if n_samples < 100:
        raise ConfigError(f"fit_family: n_samples must be >= 100, got {n_samples}")
    step = progress if progress is not None else (lambda stage: None)
    t0 = time.perf_counter()
    name = feature_map or model.feature_map
    base, eta = _fit_sample(
        controller, name, n_samples, rng, dt, margin, points_per_manoeuvre, step
    )
    n_val = n_samples if n_validation is None else int(n_validation)
    val = _validate(base, controller, eta, n_val, rng, dt)
    step("validation")

    meta = {
        "n_samples": int(n_samples),
        "n_validation": n_val,
        "seed": seed,
        "dt": float(dt),
        "margin": float(margin),
        "validation_shortfall": val.shortfall,
        "validation_extra_margin": val.extra,
        "points_per_manoeuvre": int(points_per_manoeuvre),
        "controller": repr(controller),
        "controller_config": controller.config(),
        "fit_seconds": round(time.perf_counter() - t0, 2),
    }
    fam = FittedFamily(
        model,
        controller.name,
        controller.latency,
        name,
        base.centre_coef,
        base.beta_coef,
        base.gamma_coef,
        val.eta,
        meta,
    )
    fam.meta.update(_volumes(fam, model, controller.latency, val.states))
    step("volumes")
    return fam
