"""Reactive sets S_r(x): smooth state-dependent ellipsoids (paper eq. ReactEllipse).

A :class:`ReactiveSetFamily` maps a state x to an ellipsoid ``E = {c(x) + M(x) z : |z| <= 1}``
(DESIGN.md section 4) that must contain every manoeuvre the reactive controller can fly from x,
body radius included (paper Definition 1: S_r(x) is the union over obstacles of the reactive paths).
``ellipsoid(x)`` has ONE body for numpy and CasADi (the NLP evaluates it on symbolic states), and
is smooth: magnitudes enter as ``sqrt(s^2 + eps^2)``, never through ``abs``/``max``/``if``.

Two kinds:

- ``"closed_form"``: derived from the limits (:func:`closed_form_family`). The point mass and the
  diff drive are proofs; the quadrotor's is a two-phase bound (see :class:`CapsuleClosedForm`).
- ``"fitted"``: tighter families fitted to simulated manoeuvres over sampled states
  (:func:`secure3d.reactive.fitting.fit_family`). :mod:`secure3d.reactive.family_store` finds the
  one for a vehicle: shipped JSON in ``secure3d/reactive/data``, the user's cache, or a fit made on
  demand and checked for containment before it is used.

:func:`check_containment` rolls out the controller from fresh random states and reports the fraction
of manoeuvre points whose body ball lies inside the ellipsoid of the initial state, the worst excess
and the volume ratio against the closed form.
"""

from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from secure3d.dynamics import _symbolic as sym
from secure3d.dynamics.base import VehicleModel
from secure3d.dynamics.diff_drive import DiffDrive
from secure3d.errors import ConfigError
from secure3d.reactive import _clearance
from secure3d.reactive import features as feat
from secure3d.reactive.sampling import sample_hold_controls, sample_obstacles, sample_states

FAMILY_KINDS = ("closed_form", "fitted")
CONTROLLERS = ("braking", "mpc")
FORMAT_VERSION = 1

#: Smoothing speed of the closed forms (m/s); the error it makes is added to the capsule radius.
CLOSED_FORM_EPS = 1e-2
#: Points whose cheap clearance bound exceeds the body radius by this much (m) are not searched
#: exactly in :func:`check_containment` (they are inside by a wide margin).
CHECK_SKIP_MARGIN = 0.05

SQRT2 = math.sqrt(2.0)


class ReactiveSetFamily(ABC):
    """A state-dependent ellipsoid ``E(x) = {c(x) + M(x) z : |z| <= 1}`` bounding S_r(x).

    Attributes
    ----------
    model : the vehicle model the family belongs to.
    model_name, controller_name : e.g. ``"point_mass"``, ``"braking"``.
    kind : ``"closed_form"`` or ``"fitted"``.
    latency : reaction latency (s) the family accounts for.
    body_radius : the body radius (m) it includes.
    """

    kind: str

    def __init__(self, model: VehicleModel, controller_name: str, latency: float):
        if controller_name not in CONTROLLERS:
            raise ConfigError(f"controller: must be one of {CONTROLLERS}, got {controller_name!r}")
        lat = float(latency)
        if not math.isfinite(lat) or lat < 0:
            raise ConfigError(f"latency: must be finite and >= 0, got {latency!r}")
        self.model = model
        self.model_name = model.name
        self.controller_name = controller_name
        self.latency = lat
        self.body_radius = model.body_radius

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.model_name}, {self.controller_name}, kind={self.kind}, "
            f"latency={self.latency})"
        )

    @abstractmethod
    def _components(self, xs: list[Any], m: ModuleType) -> tuple[list[Any], list[list[Any]]]:
        """Centre (3 components) and shape (3x3 nested components) from state components."""

    def ellipsoid(self, x: Any) -> tuple[Any, Any]:
        """The reactive-set ellipsoid of state ``x`` (eq. ReactEllipse).

        Parameters
        ----------
        x : (nx,) or (N, nx) float, or a CasADi column of length nx.

        Returns
        -------
        c : (3,) / (N, 3) float, or CasADi 3-vector: centre (m).
        M : (3, 3) / (N, 3, 3) float, or CasADi 3x3: symmetric positive definite shape (m).
        """
        cas = sym.is_casadi(x)
        c, M = self._components(sym.split(x, self.model.nx, "x"), sym.math_of(x))
        return sym.stack(c, cas), sym.matrix(M, cas)

    def ellipsoid_batch(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Vectorised :meth:`ellipsoid`: X (N, nx) -> C (N, 3), M (N, 3, 3) float."""
        X = np.asarray(X, dtype=float)
        if X.ndim != 2 or X.shape[1] != self.model.nx:
            raise ValueError(
                f"ellipsoid_batch: expected X of shape (N, {self.model.nx}), got {X.shape}"
            )
        return self.ellipsoid(X)

    def volume_batch(self, X: np.ndarray) -> np.ndarray:
        """Volumes (m^3) of the ellipsoids of X (N, nx): ``4/3 pi det M``, shape (N,)."""
        _, M = self.ellipsoid_batch(X)
        return 4.0 / 3.0 * math.pi * np.abs(np.linalg.det(M))

    def describe(self) -> dict[str, Any]:
        """Plain-data summary (model, controller, kind, latency, body radius)."""
        return {
            "model": self.model_name,
            "controller": self.controller_name,
            "kind": self.kind,
            "latency": self.latency,
            "body_radius": self.body_radius,
        }


# ---- closed forms ------------------------------------------------------------------------------


@dataclass(frozen=True)
class CapsuleBound:
    """Parameters of a capsule bound on the manoeuvre (see :class:`CapsuleClosedForm`).

    Attributes
    ----------
    decel : braking deceleration a_b (m/s^2) after the reaction phase.
    coast : time (s) the reference path coasts at the initial velocity before braking.
    error_accel : bound (m/s^2) on |actual acceleration - reference acceleration| during the
        reaction phase.
    error_time : duration (s) of the reaction phase.
    extra : further isotropic growth (m), e.g. the smooth approach to rest.
    """

    decel: float
    coast: float = 0.0
    error_accel: float = 0.0
    error_time: float = 0.0
    extra: float = 0.0


class CapsuleClosedForm(ReactiveSetFamily):
    """Closed-form reactive set of a vehicle braking along -v (point mass, quadrotor).

    Reference manoeuvre: coast for ``coast`` seconds, then brake at ``decel`` along -v: a straight
    segment from p of length ``l = s coast + s^2 / (2 decel)``. The braking velocity map (one step
    of the proximal operator of ``decel dt |.|``, or its continuous flow) is non-expansive, so a
    velocity error of at most ``error_accel * error_time`` gained during the reaction phase persists
    but does not grow: every point of the actual path lies within
    ``delta = a_e T^2 / 2 + a_e T (s + a_e T) / decel + extra`` of the segment (a_e = error_accel,
    T = error_time). The body sweeps the capsule of radius ``rho = r + delta`` around it, and the
    ellipsoid with semi-axes ``sqrt2 (l/2 + rho)`` along v and ``sqrt2 rho`` across, centred at
    ``p + (l/2) v_hat``, contains that capsule (DESIGN.md section 4: the rim point gives
    ``1/2 + 1/2 <= 1``). Smoothly::

        c = p + (coast/2 + s_e / (4 decel)) v
        M = sqrt2 (rho I + (coast / (2 s_e) + 1 / (4 decel)) v v^T),   s_e = sqrt(s^2 + eps^2)

    ``s_e`` over-estimates s by at most eps, which moves the centre by at most
    ``eps^2 / (8 decel)`` and shortens the coasting axis by at most ``coast eps / 2``; both are
    added to rho.

    Point mass: ``coast = latency``, ``error_accel`` = the largest held acceleration, ``error_time
    = latency``: a proof. Quadrotor: ``coast = 0``, braking reference ``decel`` = the law's
    deceleration; the reaction phase is the time to turn the thrust axis by the largest angle
    between a tilted attitude and the braking attitude at ``max_rate`` (plus latency), with the
    thrust-direction error ``|t| sin(angle)`` as ``error_accel``. That bound assumes the attitude
    loop has aligned the thrust after the reaction phase; it is not a proof, and its containment is
    established empirically by :func:`check_containment`.
    """

    kind = "closed_form"

    def __init__(self, model: VehicleModel, bound: CapsuleBound, latency: float = 0.0):
        if getattr(model, "closed_form", None) != "capsule":
            raise ConfigError(f"CapsuleClosedForm: unsupported model {model.name!r}")
        super().__init__(model, "braking", latency)
        self.bound = bound

    def _components(self, xs: list[Any], m: ModuleType) -> tuple[list[Any], list[list[Any]]]:
        b, r, eps = self.bound, self.body_radius, CLOSED_FORM_EPS
        p, v = xs[0:3], xs[3:6]
        s = sym.smooth_norm(v, eps, m)
        a_e, T = b.error_accel, b.error_time
        slack = b.coast * eps / 2 + eps * eps / (8 * b.decel)
        rho = r + 0.5 * a_e * T * T + a_e * T * (s + a_e * T) / b.decel + b.extra + slack
        alpha = b.coast / 2 + s / (4 * b.decel)
        k = b.coast / (2 * s) + 1.0 / (4 * b.decel)
        c = [p[i] + alpha * v[i] for i in range(3)]
        M = [
            [SQRT2 * ((rho if i == j else 0.0) + k * v[i] * v[j]) for j in range(3)]
            for i in range(3)
        ]
        return c, M


class DiffDriveClosedForm(ReactiveSetFamily):
    """Closed-form reactive set of the braking differential drive (a proof).

    With v the signed speed, omega the angular speed, a_b = max_accel, alpha_b = max_ang_accel and
    held accelerations up to the same bounds during the latency t_d:

    - reference segment from p along the heading h of signed length ``v (t_d + |v| / (2 a_b))``;
    - the path is at most ``E = a t_d^2 / 2 + (2 |v| a t_d + a^2 t_d^2) / (2 a_b)`` longer, and any
      reversing during the latency is shorter than E;
    - the heading turns by at most ``Theta = |w| t_d + alpha t_d^2 / 2 + (|w| + alpha t_d)^2 /
      (2 alpha_b)``, so the lateral deviation is at most ``L sin(Theta) <= L min(Theta, 1)`` with L
      the path length (and for Theta > pi/2 the whole path is within L of p);
    - hence every point is within ``delta = E + L g(Theta)`` of the segment, g a smooth upper bound
      of min(Theta, 1), and the capsule ellipsoid of :class:`CapsuleClosedForm` with
      ``rho = r + delta`` contains the swept body.
    """

    kind = "closed_form"
    #: Smoothing width of the smooth minimum (rad); g overestimates min(Theta, 1) by <= this / 2.
    SMOOTH_MIN = 0.05

    def __init__(self, model: DiffDrive, latency: float = 0.0):
        if getattr(model, "closed_form", None) != "heading_capsule":
            raise ConfigError(f"DiffDriveClosedForm: unsupported model {model.name!r}")
        super().__init__(model, "braking", latency)

    def _components(self, xs: list[Any], m: ModuleType) -> tuple[list[Any], list[list[Any]]]:
        lim: Any = self.model.limits
        r, eps, td = self.body_radius, CLOSED_FORM_EPS, self.latency
        a, al = lim.max_accel, lim.max_ang_accel
        p = self.model._position(xs, m)
        th, v, w = xs[2], xs[3], xs[4]
        h = [m.cos(th), m.sin(th), 0.0]
        sv = m.sqrt(v * v + eps * eps)
        sw = m.sqrt(w * w + eps * eps)
        half = 0.5 * sv * (td + sv / (2 * a))
        err = 0.5 * a * td * td + (2 * sv * a * td + a * a * td * td) / (2 * a)
        length = 2 * half + err
        theta = sw * td + 0.5 * al * td * td + (sw + al * td) ** 2 / (2 * al)
        k = self.SMOOTH_MIN
        g = 0.5 * (theta + 1 - m.sqrt((theta - 1) ** 2 + k * k)) + 0.5 * k
        rho = r + err + length * g + eps * eps / (8 * a)
        alpha = 0.5 * v * (td + sv / (2 * a))
        c = [p[i] + alpha * h[i] for i in range(3)]
        M = [
            [SQRT2 * ((rho if i == j else 0.0) + half * h[i] * h[j]) for j in range(3)]
            for i in range(3)
        ]
        return c, M


def closed_form_family(
    model: VehicleModel, latency: float = 0.0, controller: Any | None = None
) -> ReactiveSetFamily:
    """The closed-form reactive set of the braking controller (DESIGN.md section 4).

    Parameters
    ----------
    model : PointMass, Quadrotor or DiffDrive.
    latency : reaction latency (s) during which any control within the limits may be held.
    controller : quadrotor only: the :class:`~secure3d.reactive.controllers.BrakingController`
        whose gains the bound uses (default gains otherwise).

    Returns
    -------
    ReactiveSetFamily with ``kind == "closed_form"``.
    """
    lat = float(latency)
    if not math.isfinite(lat) or lat < 0:
        raise ConfigError(f"latency: must be finite and >= 0, got {latency!r}")
    kind = getattr(model, "closed_form", None)
    if kind == "capsule":
        from secure3d.reactive.controllers import BrakingController

        # The bound uses the braking law's deceleration and gains where the vehicle's bound
        # depends on them (the quadrotor's); the point mass's reads its limits only.
        ctrl = controller if controller is not None else BrakingController(model, lat)
        decel, gains = getattr(ctrl, "deceleration", None), getattr(ctrl, "gains", None)
        bound = CapsuleBound(*model.braking_capsule(lat, decel, gains))
        return CapsuleClosedForm(model, bound, lat)
    if kind == "heading_capsule":
        return DiffDriveClosedForm(model, lat)
    raise ConfigError(f"closed_form_family: unsupported model {getattr(model, 'name', model)!r}")


# ---- fitted families ---------------------------------------------------------------------------


class FittedFamily(ReactiveSetFamily):
    """Family fitted to simulated manoeuvres (see :mod:`secure3d.reactive.features`).

    ``c = p + sum_k a_k phi_k``, ``M = (beta + eta) I + sum_d gamma_d d_d d_d^T`` with
    ``beta = b . psi``, ``eta = e . psi``, ``gamma_d = G_d . psi``.

    Parameters
    ----------
    model : the vehicle model.
    controller_name : ``"braking"`` or ``"mpc"``.
    latency : latency (s) the manoeuvres were simulated with.
    feature_map : name in :data:`secure3d.reactive.features.FEATURE_MAPS`.
    centre : (K,) float; beta, eta : (J,) float; gamma : (D, J) float.
    meta : fitting settings and statistics (stored in the JSON).
    """

    kind = "fitted"

    def __init__(
        self,
        model: VehicleModel,
        controller_name: str,
        latency: float,
        feature_map: str,
        centre: np.ndarray,
        beta: np.ndarray,
        gamma: np.ndarray,
        eta: np.ndarray,
        meta: dict[str, Any] | None = None,
    ):
        super().__init__(model, controller_name, latency)
        K, J, D = feat.sizes(feature_map, model.nx)
        self.feature_map = feature_map
        self.centre_coef = _coef(centre, (K,), "centre")
        self.beta_coef = _coef(beta, (J,), "beta")
        self.gamma_coef = _coef(gamma, (D, J), "gamma")
        self.eta_coef = _coef(eta, (J,), "eta")
        if (
            np.any(self.gamma_coef < 0)
            or np.any(self.eta_coef[1:] < 0)
            or np.any(self.beta_coef[1:] < 0)
        ):
            raise ConfigError(
                "fitted family: shape coefficients must be >= 0 (positive definiteness)"
            )
        if self.beta_coef[0] + self.eta_coef[0] <= 0:
            raise ConfigError("fitted family: constant shape term beta_0 + eta_0 must be > 0")
        self.meta = dict(meta or {})

    def _components(self, xs: list[Any], m: ModuleType) -> tuple[list[Any], list[list[Any]]]:
        f = feat.features(self.feature_map, xs, m)
        p = self.model._position(xs, m)
        c = [
            p[i] + sum(a * phi[i] for a, phi in zip(self.centre_coef, f.centre, strict=True))
            for i in range(3)
        ]
        iso = sum(
            (b + e) * psi
            for b, e, psi in zip(self.beta_coef, self.eta_coef, f.scalars, strict=True)
        )
        gam = [
            sum(g * psi for g, psi in zip(row, f.scalars, strict=True)) for row in self.gamma_coef
        ]
        M = [
            [
                (iso if i == j else 0.0)
                + sum(gd * d[i] * d[j] for gd, d in zip(gam, f.directions, strict=True))
                for j in range(3)
            ]
            for i in range(3)
        ]
        return c, M

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form stored as JSON (see :func:`save_family`)."""
        return {
            "format": FORMAT_VERSION,
            **self.describe(),
            "limits": dataclasses.asdict(self.model.limits),
            "feature_map": self.feature_map,
            "coefficients": {
                "centre": self.centre_coef.tolist(),
                "beta": self.beta_coef.tolist(),
                "gamma": self.gamma_coef.tolist(),
                "eta": self.eta_coef.tolist(),
            },
            "meta": self.meta,
        }


def _coef(value: Any, shape: tuple[int, ...], name: str) -> np.ndarray:
    arr = np.array(value, dtype=float)
    if arr.shape != shape or not np.all(np.isfinite(arr)):
        raise ConfigError(
            f"fitted family: coefficients.{name} must be finite with shape {shape}, got {arr.shape}"
        )
    arr.flags.writeable = False
    return arr


# ---- containment check -------------------------------------------------------------------------


@dataclass(frozen=True)
class ContainmentReport:
    """Outcome of :func:`check_containment`.

    Attributes
    ----------
    family : ``"<model>/<controller>/<kind>"``.
    n_manoeuvres : manoeuvres simulated.
    n_points : manoeuvre points checked (every integration step of every manoeuvre).
    n_outside : points whose body ball is not inside the initial state's ellipsoid.
    n_manoeuvres_outside : manoeuvres with at least one such point.
    fraction_inside : ``1 - n_outside / n_points``.
    worst_excess : largest ``r - clearance`` (m): how far the worst body ball reaches outside
        (negative when contained: then minus the smallest slack). Exact where it matters (points
        within ``CHECK_SKIP_MARGIN`` of the boundary), otherwise an upper bound.
    mean_volume, mean_volume_closed_form : mean ellipsoid volume (m^3) over the sampled states of
        this family and of the braking closed form.
    volume_ratio_vs_closed_form : ``mean_volume / mean_volume_closed_form``.
    latency, dt : the simulation settings.
    """

    family: str
    n_manoeuvres: int
    n_points: int
    n_outside: int
    n_manoeuvres_outside: int
    fraction_inside: float
    worst_excess: float
    mean_volume: float
    mean_volume_closed_form: float
    volume_ratio_vs_closed_form: float
    latency: float
    dt: float

    @property
    def passed(self) -> bool:
        """Every body ball of every manoeuvre is inside its ellipsoid."""
        return self.n_outside == 0

    def __str__(self) -> str:
        return (
            f"{self.family}: {100 * self.fraction_inside:.4f}% of {self.n_points} points inside "
            f"({self.n_manoeuvres_outside}/{self.n_manoeuvres} manoeuvres leave), worst excess "
            f"{self.worst_excess:+.4f} m, volume {self.mean_volume:.4g} m^3 = "
            f"{self.volume_ratio_vs_closed_form:.3f} x closed form"
        )


def manoeuvre_points(
    controller: Any,
    X0: np.ndarray,
    dt: float,
    u_hold: np.ndarray | None = None,
    chunk: int = 2000,
    **context: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Positions along the manoeuvres from each state, trimmed once each has stopped.

    Returns
    -------
    points : (n_points, 3) float, grouped by manoeuvre.
    offsets : (N + 1,) int: manoeuvre k is ``points[offsets[k]:offsets[k+1]]``.
    """
    model = controller.model
    groups: list[np.ndarray] = []
    for start in range(0, len(X0), chunk):
        sl = slice(start, start + chunk)
        ctx = {k: v[sl] for k, v in context.items()}
        uh = None if u_hold is None else u_hold[sl]
        _, traj = controller.rollout_batch(X0[sl], dt=dt, u_hold=uh, **ctx)
        P = model.position(traj)  # (n, T, 3)
        moving = np.linalg.norm(np.diff(P, axis=1), axis=2) > 0
        last = P.shape[1] - 1 - np.argmax(moving[:, ::-1], axis=1)
        last = np.where(moving.any(axis=1), last, 0)
        keep = np.arange(P.shape[1])[None, :] <= last[:, None]
        groups.append((P[keep], keep.sum(axis=1)))
    points = np.concatenate([g[0] for g in groups])
    counts = np.concatenate([g[1] for g in groups])
    return points, np.concatenate([[0], np.cumsum(counts)])


def check_containment(
    family: ReactiveSetFamily,
    controller: Any,
    n_samples: int = 10_000,
    rng: np.random.Generator | None = None,
    state_sampler: Callable[[VehicleModel, int, np.random.Generator], np.ndarray] | None = None,
    dt: float = 0.01,
    chunk: int = 2000,
) -> ContainmentReport:
    """Check a family against fresh simulated manoeuvres.

    Samples ``n_samples`` states (``state_sampler``, default
    :func:`secure3d.reactive.sampling.sample_states`), random held controls for the controller's
    latency, and for the MPC random obstacles; rolls out the controller (vectorised); and tests that
    the body ball at every integration step lies inside the ellipsoid of the initial state, exactly
    (:mod:`secure3d.reactive._clearance`).

    Parameters
    ----------
    family : the family under test.
    controller : the reactive controller it claims to bound (same model, latency <= the family's).
    n_samples : number of manoeuvres.
    rng : generator; use a seed different from the fitting seeds (stored in the family's meta).
    state_sampler : ``(model, n, rng) -> (n, nx)`` states.
    dt : integration step (s).
    chunk : manoeuvres simulated at once (memory: chunk x steps x nx floats).

    Returns
    -------
    ContainmentReport
    """
    model = family.model
    if controller.model is not model and controller.model.name != model.name:
        raise ConfigError(
            f"check_containment: controller is for {controller.model.name}, family for {model.name}"
        )
    if controller.latency > family.latency + 1e-12:
        raise ConfigError(
            f"check_containment: controller latency {controller.latency} s exceeds the "
            f"family's {family.latency} s"
        )
    if controller.name != family.controller_name:
        raise ConfigError(
            f"check_containment: controller {controller.name!r} but family for "
            f"{family.controller_name!r}"
        )
    rng = np.random.default_rng() if rng is None else rng
    sampler = sample_states if state_sampler is None else state_sampler
    X0 = np.asarray(sampler(model, int(n_samples), rng), dtype=float)
    u_hold = sample_hold_controls(model, len(X0), rng) if controller.latency > 0 else None
    context = {}
    if controller.name == "mpc":
        lo, hi = sample_obstacles(model, X0, rng)
        context = {"obstacle_lo": lo, "obstacle_hi": hi}
    points, offsets = manoeuvre_points(controller, X0, dt, u_hold, chunk, **context)
    owner = np.repeat(np.arange(len(X0)), np.diff(offsets))
    C, M = family.ellipsoid_batch(X0)
    r = model.body_radius
    clear = _clearance.clearance(points, owner, C, M, enough=r + CHECK_SKIP_MARGIN)
    excess = r - clear
    outside = excess > 0
    vol = family.volume_batch(X0)
    closed = closed_form_family(model, family.latency).volume_batch(X0)
    return ContainmentReport(
        family=f"{family.model_name}/{family.controller_name}/{family.kind}",
        n_manoeuvres=len(X0),
        n_points=len(points),
        n_outside=int(outside.sum()),
        n_manoeuvres_outside=int(np.unique(owner[outside]).size),
        fraction_inside=float(1.0 - outside.mean()),
        worst_excess=float(excess.max()),
        mean_volume=float(vol.mean()),
        mean_volume_closed_form=float(closed.mean()),
        volume_ratio_vs_closed_form=float(vol.mean() / closed.mean()),
        latency=controller.latency,
        dt=float(dt),
    )
