"""Vehicle model interface shared by the planner (CasADi), the simulator and the reactive module.

A model is a thin class over component kernels (see :mod:`secure3d.dynamics._symbolic`): each of
``f``, ``path_constraints``, ``position``, ``velocity``, ``body_rotation`` and ``camera_pose`` has
ONE body that evaluates numpy states ``(nx,)``, numpy batches ``(N, nx)`` and CasADi columns.
Rotations come from :mod:`secure3d.geometry.transforms` (body x forward, y left, z up; optical z
forward, x right, y down; positive mount pitch looks down).
Limits are frozen dataclasses validated in ``__post_init__``; bad values raise
:class:`~secure3d.errors.ConfigError` naming the field.
"""

from __future__ import annotations

import dataclasses
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from types import ModuleType
from typing import Any, ClassVar

import casadi as ca
import numpy as np

from secure3d.dynamics import _symbolic as sym
from secure3d.dynamics.integrate import rk4_step
from secure3d.errors import ConfigError
from secure3d.geometry import transforms
from secure3d.validation import is_real

Vec3 = tuple[float, float, float]


def check_positive(owner: str, name: str, value: Any, *, allow_zero: bool = False) -> float:
    """Return ``value`` as a float or raise :class:`ConfigError` naming ``owner.name``.

    Parameters
    ----------
    owner : class name used in the message (e.g. ``"PointMassLimits"``).
    name : field name (the key scenario files use under ``vehicle.limits``).
    value : the user's value; must be a real number, finite and > 0 (>= 0 with ``allow_zero``).
    """
    if not is_real(value, numpy=True):
        raise ConfigError(f"{owner}.{name}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ConfigError(f"{owner}.{name}: must be finite and {bound}, got {value!r}")
    return v


def normalise_fields(obj: Any, owner: str, *, allow_zero: tuple[str, ...] = ()) -> None:
    """Validate every float field of a frozen limits dataclass in place (:func:`check_positive`)."""
    for f in dataclasses.fields(obj):
        if f.type in ("float", float):
            value = check_positive(
                owner, f.name, getattr(obj, f.name), allow_zero=f.name in allow_zero
            )
            object.__setattr__(obj, f.name, value)


@dataclass(frozen=True)
class CameraMount:
    """Where the camera sits on the body.

    Attributes
    ----------
    pitch : float
        Downward pitch of the optical axis from body x (rad, positive down), |pitch| < pi/2.
    offset : (3,) float
        Camera position in the body frame (m; x forward, y left, z up).
    """

    pitch: float = 0.0
    offset: Vec3 = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        p = self.pitch
        if not is_real(p, numpy=True):
            raise ConfigError(f"CameraMount.pitch: expected a number (rad), got {p!r}")
        if not (math.isfinite(float(p)) and abs(float(p)) < math.pi / 2):
            raise ConfigError(
                f"CameraMount.pitch: must be finite with |pitch| < pi/2 rad, got {p!r}"
            )
        object.__setattr__(self, "pitch", float(p))
        try:
            off = np.asarray(self.offset, dtype=float)
        except (TypeError, ValueError):
            raise ConfigError(
                f"CameraMount.offset: expected 3 numbers, got {self.offset!r}"
            ) from None
        if off.shape != (3,) or not np.all(np.isfinite(off)):
            raise ConfigError(f"CameraMount.offset: expected 3 finite numbers, got {self.offset!r}")
        object.__setattr__(self, "offset", (float(off[0]), float(off[1]), float(off[2])))


class VehicleModel(ABC):
    """A vehicle: dynamics, limits, body radius and camera mount.

    Subclasses define the component kernels ``_f``, ``_path``, ``_position`` and ``_velocity``, and
    :meth:`body_rotation`; the public methods below stack them for numpy or CasADi.

    Attributes
    ----------
    name : model name (``"point_mass"``, ``"quadrotor"``, ``"diff_drive"``).
    state_names, control_names : names of the state and control entries.
    limits : the model's frozen limits dataclass.
    body_radius : radius of the ball bounding the body (m).
    mount : :class:`CameraMount`.
    u_lo, u_hi : (nu,) float, control box bounds.
    x_lo, x_hi : (nx,) float, state box bounds (+-inf where none).
    """

    name: ClassVar[str]
    state_names: ClassVar[tuple[str, ...]]
    control_names: ClassVar[tuple[str, ...]]
    limits_type: ClassVar[type]
    #: Moves in a horizontal plane at a fixed height (the paper's planar robot).
    planar: ClassVar[bool] = False
    #: Its heading is its direction of travel (non-holonomic): a path's yaw is its tangent's.
    heading_follows_path: ClassVar[bool] = False
    #: p' = v, v' = u[:3]: position (0:3) and velocity (3:6) driven by an acceleration command (the
    #: MPC reactive controller's prediction model).
    double_integrator: ClassVar[bool] = False
    #: State entries holding an attitude quaternion (w, x, y, z), or None without one.
    quaternion_slice: ClassVar[slice | None] = None
    #: The feedback law that makes this vehicle follow a plan: a key of
    #: ``secure3d.simulation.tracking.TRACKERS`` (a new vehicle names an existing law, or adds one).
    tracker_kind: ClassVar[str]

    def __init__(
        self, limits: Any = None, body_radius: float = 0.2, mount: CameraMount | None = None
    ):
        if limits is None:
            limits = self.limits_type()
        if not isinstance(limits, self.limits_type):
            raise ConfigError(
                f"{type(self).__name__}.limits: expected {self.limits_type.__name__}, "
                f"got {limits!r}"
            )
        r = check_positive(type(self).__name__, "body_radius", body_radius)
        if r > 5.0:
            raise ConfigError(f"{type(self).__name__}.body_radius: {r} m is absurd (> 5 m)")
        mount = CameraMount() if mount is None else mount
        if not isinstance(mount, CameraMount):
            raise ConfigError(f"{type(self).__name__}.mount: expected CameraMount, got {mount!r}")
        self.limits = limits
        self.body_radius = r
        self.mount = mount
        lo, hi = self._control_bounds()
        self.u_lo, self.u_hi = _frozen(lo), _frozen(hi)
        lo, hi = self._state_bounds()
        self.x_lo, self.x_hi = _frozen(lo), _frozen(hi)

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}({self.limits!r}, body_radius={self.body_radius}, "
            f"mount={self.mount!r})"
        )

    # ---- sizes -----------------------------------------------------------------------------------
    @property
    def nx(self) -> int:
        """Number of states."""
        return len(self.state_names)

    @property
    def nu(self) -> int:
        """Number of controls."""
        return len(self.control_names)

    # ---- component kernels (one body for numpy and CasADi) ---------------------------------------
    @abstractmethod
    def _f(self, xs: list[Any], us: list[Any], m: ModuleType) -> list[Any]: ...

    @abstractmethod
    def _path(self, xs: list[Any], us: list[Any], m: ModuleType) -> list[Any]: ...

    @abstractmethod
    def _position(self, xs: list[Any], m: ModuleType) -> list[Any]: ...

    @abstractmethod
    def _velocity(self, xs: list[Any], m: ModuleType) -> list[Any]: ...

    @abstractmethod
    def _control_bounds(self) -> tuple[list[float], list[float]]: ...

    @abstractmethod
    def _state_bounds(self) -> tuple[list[float], list[float]]: ...

    # ---- public API, numpy and CasADi ----------------------------------------------------------
    def f(self, x: Any, u: Any) -> Any:
        """State derivative ``xdot = f(x, u)``.

        Parameters
        ----------
        x : (nx,) or (N, nx) float, or CasADi column of length nx.
        u : (nu,) or (N, nu) float, or CasADi column of length nu.

        Returns
        -------
        xdot : same layout as ``x``.
        """
        if type(x) is np.ndarray and type(u) is np.ndarray and x.dtype == u.dtype == np.float64:
            # numbers (every simulation step): the same values without the CasADi dispatch; one
            # state's components as floats (the same double arithmetic as numpy's scalars, faster)
            if x.shape == (self.nx,) and u.shape == (self.nu,):
                xs, us = x.tolist(), u.tolist()
            else:
                xs, us = sym.split_numbers(x, self.nx, "x"), sym.split_numbers(u, self.nu, "u")
            return sym.stack(self._f(xs, us, np), False)
        cas = sym.is_casadi(x, u)
        m = sym.math_of(x, u)
        return sym.stack(self._f(sym.split(x, self.nx, "x"), sym.split(u, self.nu, "u"), m), cas)

    def path_constraints(self, x: Any, u: Any) -> Any:
        """Path constraints ``g(x, u) <= 0`` beyond the box bounds (may have zero entries).

        Returns
        -------
        g : (k,) or (N, k) float, or CasADi column of length k.
        """
        cas = sym.is_casadi(x, u)
        m = sym.math_of(x, u)
        g = self._path(sym.split(x, self.nx, "x"), sym.split(u, self.nu, "u"), m)
        if not g and not cas:
            return np.zeros((*np.shape(x)[:-1], 0))
        return sym.stack(g, cas)

    def position(self, x: Any) -> Any:
        """Body centre (m): (3,) / (N, 3) float, or CasADi 3-vector."""
        return sym.stack(
            self._position(sym.split(x, self.nx, "x"), sym.math_of(x)), sym.is_casadi(x)
        )

    def velocity(self, x: Any) -> Any:
        """World velocity (m/s): (3,) / (N, 3) float, or CasADi 3-vector."""
        return sym.stack(
            self._velocity(sym.split(x, self.nx, "x"), sym.math_of(x)), sym.is_casadi(x)
        )

    @abstractmethod
    def body_rotation(self, x: Any) -> Any:
        """World-from-body rotation: (3, 3) / (N, 3, 3) float, or CasADi 3x3."""

    def camera_pose(self, x: Any) -> tuple[Any, Any]:
        """Camera pose from the state and the mount.

        Returns
        -------
        R_world_from_optical : (3, 3) / (N, 3, 3) float, or CasADi 3x3 (optical z forward, x right,
            y down).
        origin : (3,) / (N, 3) float, or CasADi 3-vector: ``p + R_wb @ mount.offset``.
        """
        r_wb = self.body_rotation(x)
        r_wo = transforms.camera_rotation(r_wb, self.mount.pitch)
        if sym.is_casadi(x):
            return r_wo, self.position(x) + ca.mtimes(r_wb, ca.DM(self.mount.offset))
        return r_wo, self.position(x) + np.einsum("...ij,j->...i", r_wb, self.mount.offset)

    # ---- numpy only ----------------------------------------------------------------------------
    def f_batch(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """Vectorised ``f`` over N states: X (N, nx), U (N, nu) -> (N, nx) float."""
        X, U = np.asarray(X, dtype=float), np.asarray(U, dtype=float)
        if X.ndim != 2 or X.shape[1] != self.nx or U.shape != (len(X), self.nu):
            raise ValueError(
                f"f_batch: expected X (N, {self.nx}) and U (N, {self.nu}), got {X.shape}, {U.shape}"
            )
        return self.f(X, U)

    def step(self, x: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        """One RK4 step (control held), followed by :meth:`project_state`. x (nx,) -> (nx,)."""
        return self.project_state(
            rk4_step(self.f, np.asarray(x, dtype=float), np.asarray(u, dtype=float), dt)
        )

    def step_batch(self, X: np.ndarray, U: np.ndarray, dt: float) -> np.ndarray:
        """Vectorised :meth:`step`: X (N, nx), U (N, nu) -> (N, nx)."""
        return self.project_state(
            rk4_step(self.f_batch, np.asarray(X, dtype=float), np.asarray(U, dtype=float), dt)
        )

    def speed(self, x: np.ndarray) -> np.ndarray:
        """Speed |v| (m/s): scalar for (nx,), (N,) for (N, nx)."""
        return np.linalg.norm(self.velocity(x), axis=-1)

    def project_state(self, x: np.ndarray) -> np.ndarray:
        """Map a numerically drifted state back onto the state manifold (identity by default)."""
        return x

    @abstractmethod
    def yaw(self, x: np.ndarray) -> np.ndarray:
        """Heading of the body x axis about world z (rad)."""

    @abstractmethod
    def initial_state(
        self, position: Any, velocity: Any = (0.0, 0.0, 0.0), yaw: float = 0.0
    ) -> np.ndarray:
        """A state at ``position`` (m) moving with ``velocity`` (m/s), heading ``yaw`` (rad)."""

    def initial_states(
        self, positions: np.ndarray, velocities: np.ndarray, yaws: np.ndarray
    ) -> np.ndarray:
        """:meth:`initial_state` of N rows at once: (N, 3), (N, 3), (N,) -> (N, nx) float."""
        rows = [
            self.initial_state(p, v, y)
            for p, v, y in zip(
                np.asarray(positions, float), np.asarray(velocities, float), yaws, strict=True
            )
        ]
        return np.stack(rows) if rows else np.zeros((0, self.nx))

    def rest_state(self, position: Any, yaw: float = 0.0) -> np.ndarray:
        """A state at rest at ``position`` with heading ``yaw``: (nx,) float."""
        return self.initial_state(position, (0.0, 0.0, 0.0), yaw)

    def nominal_control(self, x: np.ndarray) -> np.ndarray:
        """Control that keeps the velocity (zero acceleration, or hover): (nu,) or (N, nu)."""
        return np.zeros((*np.shape(x)[:-1], self.nu))

    # -- capabilities (what callers used to learn by checking the vehicle's name) -----------------

    @property
    def speed_limit(self) -> float:
        """Largest speed (m/s)."""
        return float(self.limits.max_speed)

    @property
    def yaw_rate_limit(self) -> float:
        """Largest rate of turn of the heading (rad/s)."""
        return float(self.limits.max_yaw_rate)

    @property
    def nominal_accel(self) -> float:
        """Acceleration (m/s^2) to time-parametrise an initial guess with (the bound where the
        model has one)."""
        return float(self.limits.max_accel)

    def rest_residuals(self, x: Any) -> list[Any]:
        """Entries of state ``x`` (numpy or CasADi) that must also vanish for the robot to be at
        rest, beyond the velocity the planner already pins (e.g. a planar robot's turn rate)."""
        return []

    def turn_in_place_control(
        self, u: np.ndarray, x: np.ndarray, yaw_error: float, rate_fraction: float, dt: float
    ) -> np.ndarray:
        """``u`` (a control holding still) changed to turn the heading by ``yaw_error`` (rad), at
        up to ``rate_fraction`` of the yaw-rate limit, for a step of ``dt`` s (in place)."""
        w = rate_fraction * self.yaw_rate_limit
        u[3] = float(np.clip(3.0 * yaw_error, -w, w))
        return u

    def sample_states(
        self, positions: np.ndarray, speeds: Any, rng: np.random.Generator
    ) -> np.ndarray:
        """Random states at ``positions`` (n, 3) within the limits: ``speeds(top)`` draws (n,)
        magnitudes up to ``top``. (n, nx) float."""
        raise ConfigError(f"sample_states: no sampler for model {self.name!r}")

    def _sample_moving(
        self, positions: np.ndarray, speeds: Any, rng: np.random.Generator
    ) -> np.ndarray:
        """States (n, nx) at ``positions`` with velocities (entries 3:6) of random direction and
        magnitude ``speeds(max_speed)``; the rest zero (for the model to fill)."""
        n = len(positions)
        X = np.zeros((n, self.nx))
        X[:, :3] = positions
        X[:, 3:6] = speeds(self.limits.max_speed)[:, None] * sample_unit_vectors(n, rng)
        return X

    def sample_controls(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` random controls, uniform in the control box: (n, nu) float."""
        return self.u_lo + (self.u_hi - self.u_lo) * rng.random((n, self.nu))

    # -- the braking law of :class:`secure3d.reactive.controllers.BrakingController` ----------------
    #: The closed-form reactive set of its braking (secure3d.reactive.reactive_set.closed_form_family):
    #: "capsule" (braking along -v, bounded by :meth:`braking_capsule`), "heading_capsule" (a
    #: wheeled robot braking along its heading), or None.
    closed_form: ClassVar[str | None] = None
    #: Default feature map of a fitted reactive-set family (a key of
    #: ``secure3d.reactive.features.FEATURE_MAPS``).
    feature_map: ClassVar[str]
    #: Whether the model has a braking law (the methods below).
    has_braking_law: ClassVar[bool] = False
    #: Whether the law reads the controller's gains (then they are part of its configuration).
    braking_uses_gains: ClassVar[bool] = False

    def braking_deceleration_with(self, gains: Any) -> float:
        """The deceleration (m/s^2) the law demands: ``max_accel`` unless the model says else."""
        return self.limits.max_accel

    def braking_durations(self, deceleration: float, gains: Any) -> tuple[float, float]:
        """(twice the braking time from the top speed, settling time) in s."""
        return 2.0 * self.limits.max_speed / deceleration, 0.5

    def braking_capsule(
        self, latency: float, deceleration: float, gains: Any
    ) -> tuple[float, float, float, float, float]:
        """The capsule bound on a braking manoeuvre after ``latency`` s (``closed_form ==
        "capsule"``): deceleration, coast time, error acceleration, error time, extra growth, as
        :class:`secure3d.reactive.reactive_set.CapsuleBound` takes them."""
        raise NotImplementedError(f"{type(self).__name__} has no capsule bound")

    def braking_kernel(
        self, deceleration: float, gains: Any
    ) -> tuple[int, tuple[float, ...]] | None:
        """The compiled form of the braking manoeuvre (:mod:`secure3d.dynamics._braking_kernels`):
        the model's kind there and the law's parameters, or None (no kernel: a subclass that
        changes the dynamics or the law must return None unless it has its own)."""
        return None

    def braking_controls(
        self, X: np.ndarray, dt: float, deceleration: float, gains: Any
    ) -> np.ndarray:
        """Braking controls (N, nu) for states X (N, nx) held for ``dt`` s."""
        raise NotImplementedError(f"{type(self).__name__} has no braking law")

    def braking_at_rest(
        self, X: np.ndarray, rest: float, deceleration: float, gains: Any
    ) -> np.ndarray:
        """(N,) bool: stopped (speeds below ``rest``, and whatever else the law settles)."""
        raise NotImplementedError(f"{type(self).__name__} has no braking law")

    def guess_rates(self, states: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Make a time-parametrised guess consistent with the dynamics where that is cheap.

        Parameters
        ----------
        states : (K, nx) float, as :meth:`initial_states` builds them along a path.
        times : (K,) float, increasing node times (s).

        Returns
        -------
        states, controls : (K, nx) and (K, nu) float. The default keeps the states and holds the
            :meth:`nominal_control`; models whose states carry their own rates override this.
        """
        return states, self.nominal_control(states)


def sample_unit_vectors(n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` random directions, uniform on the sphere: (n, 3) float."""
    u = rng.normal(size=(n, 3))
    return u / np.linalg.norm(u, axis=1, keepdims=True)


def _frozen(values: list[float]) -> np.ndarray:
    arr = np.array(values, dtype=float)
    arr.flags.writeable = False
    return arr


def state_rows(
    positions: np.ndarray, velocities: np.ndarray, yaws: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows of a batched ``initial_states`` call, checked: positions (N, 3), velocities
    (N, 3), both finite, and yaws (N,) as floats; :class:`ConfigError` otherwise."""
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    v = np.asarray(velocities, dtype=float).reshape(-1, 3)
    y = np.asarray(yaws, dtype=float).reshape(-1)
    if not (len(p) == len(v) == len(y)):
        raise ConfigError(
            f"initial_states: {len(p)} positions, {len(v)} velocities and {len(y)} yaws"
        )
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(v))):
        raise ConfigError("initial_states: positions and velocities must be finite")
    return p, v, y


def vec3(value: Any, what: str) -> np.ndarray:
    """``value`` as a finite (3,) float array, or :class:`ConfigError` naming ``what``."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ConfigError(f"{what}: expected 3 numbers, got {value!r}") from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{what}: expected 3 finite numbers, got {value!r}")
    return arr
