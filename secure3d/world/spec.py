"""The scenario data model: frozen, validated dataclasses.

A :class:`Scenario` is what ``maps/*.yaml`` describes and what every other layer consumes: the true
world (seen only by the simulator), the server's claim about it (with attacks), the vehicle, the
camera, start, goal and planner settings. Loading and validating YAML lives in
:mod:`secure3d.world.scenario`; this module only defines the types and their invariants, so it can
be used to build scenarios in Python too::

    Scenario(name="demo", world=World(bounds=Bounds((0, 0, 0), (10, 10, 3)), boxes=(...)), ...)

Units are SI (metres, seconds, radians unless a field says degrees). Frames: world is z-up.

Every validation error is a :class:`~secure3d.errors.ScenarioError` whose message reads
``"<field>: <problem> (got <value>)"``; the YAML loader prefixes the file name.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np

from secure3d.dynamics import DEFAULT_MODEL
from secure3d.errors import ScenarioError
from secure3d.world.spec_fields import (  # noqa: F401  (re-exported)
    ATTACK_KINDS,
    MAX_MAP_VOXELS,
    MAX_OBSTACLES,
    MAX_WORLD_EXTENT,
    OCTOMAP_KEY_HALF_RANGE,
    VEHICLE_MODELS,
    Vec3,
    _choice,
    _count,
    _file_name,
    _fmt,
    _integer,
    _name,
    _number,
    _positive,
    _short,
    _vec3,
)
from secure3d.world.world_spec import (  # noqa: F401  (re-exported)
    Attack,
    Bounds,
    Box,
    MeshObstacle,
    Region,
    ServerMapSpec,
    World,
    box_distance,
)


@dataclass(frozen=True)
class VehicleSpec:
    """The vehicle: model name, body radius (m) and model-specific limits.

    ``limits`` maps field names of the model's limits dataclass (see :mod:`secure3d.dynamics`) to
    values; it is validated by the dynamics module when the model is built.
    """

    model: str = DEFAULT_MODEL
    body_radius: float = 0.2
    limits: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _choice(self.model, VEHICLE_MODELS, "vehicle.model")
        r = _positive(self.body_radius, "vehicle.body_radius")
        if r > 5.0:
            raise ScenarioError(f"vehicle.body_radius: must be <= 5 m (got {r})")
        limits = dict(self.limits)
        for key, value in limits.items():
            _name(key, "vehicle.limits")
            _number(value, f"vehicle.limits.{key}")
        object.__setattr__(self, "limits", limits)

    def __hash__(self) -> int:
        return hash((self.model, self.body_radius, tuple(sorted(self.limits.items()))))


@dataclass(frozen=True)
class CameraSpec:
    """Pinhole depth camera.

    width, height : image size (pixels).
    hfov_deg : horizontal field of view (degrees); the vertical one follows from the aspect ratio
        unless ``vfov_deg`` is given.
    max_range : largest depth the sensor reports (m).
    far_kind : ``"depth"`` if ``max_range`` limits z-depth (a plane), ``"range"`` if it limits the
        Euclidean range (the frustum is then inner-approximated).
    rate_hz : frame rate.
    mount_pitch_deg : downward pitch of the optical axis relative to the body x axis (degrees).
    mount_offset : camera position in the body frame (m).
    noise_std : depth noise standard deviation (m); dropout : fraction of pixels lost.
    discretize : insert frames into the robot's map as OctoMap's ``insertPointCloud`` with
        ``discretize=true``: one ray per distinct end voxel, cast to its centre. A 160x120 frame
        of the blind corner has ~2,400 distinct end voxels for 19,200 pixels, so mapping is ~5x
        faster; the occupied voxels (what reveals an obstacle) are the same. ``false``: one ray per
        pixel.
    """

    width: int = 160
    height: int = 120
    hfov_deg: float = 90.0
    vfov_deg: float | None = None
    max_range: float = 6.0
    far_kind: Literal["depth", "range"] = "depth"
    rate_hz: float = 15.0
    mount_pitch_deg: float = 0.0
    mount_offset: Vec3 = (0.0, 0.0, 0.0)
    noise_std: float = 0.0
    dropout: float = 0.0
    discretize: bool = True

    def __post_init__(self) -> None:
        if not isinstance(self.discretize, bool):
            raise ScenarioError(
                f"camera.discretize: expected true or false (got {_short(self.discretize)})"
            )
        for name in ("width", "height"):
            _integer(getattr(self, name), f"camera.{name}", 8, 4096)
        h = _positive(self.hfov_deg, "camera.hfov_deg")
        if not h < 170:
            raise ScenarioError(f"camera.hfov_deg: must be < 170 for a pinhole camera (got {h})")
        if self.vfov_deg is not None:
            v = _positive(self.vfov_deg, "camera.vfov_deg")
            if not v < 170:
                raise ScenarioError(f"camera.vfov_deg: must be < 170 (got {v})")
        _positive(self.max_range, "camera.max_range")
        _choice(self.far_kind, ("depth", "range"), "camera.far_kind")
        _positive(self.rate_hz, "camera.rate_hz")
        pitch = _number(self.mount_pitch_deg, "camera.mount_pitch_deg")
        if not -89 <= pitch <= 89:
            raise ScenarioError(f"camera.mount_pitch_deg: must be in [-89, 89] (got {pitch})")
        object.__setattr__(self, "mount_offset", _vec3(self.mount_offset, "camera.mount_offset"))
        _positive(self.noise_std, "camera.noise_std", allow_zero=True)
        if not 0 <= _number(self.dropout, "camera.dropout") < 1:
            raise ScenarioError(f"camera.dropout: must be in [0, 1) (got {self.dropout})")

    @property
    def vfov(self) -> float:
        """Vertical field of view (radians)."""
        if self.vfov_deg is not None:
            return math.radians(self.vfov_deg)
        return 2 * math.atan(math.tan(math.radians(self.hfov_deg) / 2) * self.height / self.width)

    @property
    def hfov(self) -> float:
        """Horizontal field of view (radians)."""
        return math.radians(self.hfov_deg)

    @property
    def fx(self) -> float:
        return self.width / (2 * math.tan(self.hfov / 2))

    @property
    def fy(self) -> float:
        return self.height / (2 * math.tan(self.vfov / 2))


@dataclass(frozen=True)
class StartSpec:
    """Initial state: position (m), velocity (m/s), yaw (rad, about world z)."""

    position: Vec3
    velocity: Vec3 = (0.0, 0.0, 0.0)
    yaw: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", _vec3(self.position, "start.position"))
        object.__setattr__(self, "velocity", _vec3(self.velocity, "start.velocity"))
        object.__setattr__(self, "yaw", _number(self.yaw, "start.yaw"))


@dataclass(frozen=True)
class GoalSpec:
    """Goal position (m), reached when within ``tolerance`` (m) at rest."""

    position: Vec3
    tolerance: float = 0.3

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", _vec3(self.position, "goal.position"))
        _positive(self.tolerance, "goal.tolerance")


@dataclass(frozen=True)
class PlannerSpec:
    """Planner settings a scenario can fix (all have defaults).

    nodes : collocation nodes K. lookback : ``"adaptive"`` or ``"fixed"``; lookback_steps : the
    paper's Δi for the fixed rule. solver : ``"ipopt"`` or ``"fatrop"``. reactive_family :
    ``"fitted"`` or ``"closed_form"``. controller : reactive controller, ``"braking"`` or ``"mpc"``.
    margin : clearance added to every obstacle and visibility constraint (m).
    min_obstacle_size : the smallest obstacle (m) the safety guarantee covers: every obstacle that
        contains a ball this wide is hit by every frame out to the *observed range* derived from the
        camera (:func:`secure3d.mapping.observability.observed_range`), and the planner and the
        certificate count only that far as seen. Smaller values shorten the observed range (and slow
        the secure robot) in proportion. Default 0.15 m: with the shipped 160 x 120, 90 deg camera
        (fx = 80 px) every frame hits such obstacles out to 8.4 m, beyond the shipped 5-8 m ranges,
        so there the sensor's limit (less w / 2) decides (0.1 m cuts their view to 5.6 m).
    edge_allowance : count a point as seen only where an obstacle of ``min_obstacle_size``
        touching it is surely hit even when its ball straddles the edge of the view: the sensor's
        limit counts w / 2 short, the side faces move inwards and a near face is added
        (:func:`secure3d.mapping.observability.observed_sides`). Default off: the guarantee then
        covers such obstacles once their ball is inside the image and within range
        (docs/guarantees.md measures the cost; ``beam_3d`` plans no certified route with it).
    extra_starts : further cruise-speed fractions (each in (0, 1]) the cold plan also starts from,
        keeping the fastest plan that passes (:class:`~secure3d.planning.problem.PlannerOptions`).
        Default none: set it only where one start is measured to land in a slow local optimum.
    """

    nodes: int = 40
    lookback: Literal["adaptive", "fixed"] = "adaptive"
    lookback_steps: int = 3
    solver: Literal["ipopt", "fatrop"] = "ipopt"
    reactive_family: Literal["fitted", "closed_form"] = "fitted"
    controller: Literal["braking", "mpc"] = "braking"
    margin: float = 0.02
    max_iter: int = 500
    min_obstacle_size: float = 0.15
    extra_starts: tuple[float, ...] = ()
    edge_allowance: bool = False

    def __post_init__(self) -> None:
        nodes = _integer(self.nodes, "planner.nodes", 5, 400)
        if not isinstance(self.extra_starts, (tuple, list)):
            raise ScenarioError(
                f"planner.extra_starts: must be a list (got {_short(self.extra_starts)})"
            )
        starts = tuple(_number(f, "planner.extra_starts") for f in self.extra_starts)
        if not all(0.0 < f <= 1.0 for f in starts):
            raise ScenarioError(
                f"planner.extra_starts: speed fractions must lie in (0, 1] (got {list(starts)})"
            )
        object.__setattr__(self, "extra_starts", starts)
        _positive(self.min_obstacle_size, "planner.min_obstacle_size")
        if not isinstance(self.edge_allowance, bool):
            raise ScenarioError(
                f"planner.edge_allowance: must be true or false (got {_short(self.edge_allowance)})"
            )
        _choice(self.lookback, ("adaptive", "fixed"), "planner.lookback")
        _integer(self.lookback_steps, "planner.lookback_steps", 1, nodes - 1)
        _choice(self.solver, ("ipopt", "fatrop"), "planner.solver")
        _choice(self.reactive_family, ("fitted", "closed_form"), "planner.reactive_family")
        _choice(self.controller, ("braking", "mpc"), "planner.controller")
        _positive(self.margin, "planner.margin", allow_zero=True)
        _integer(self.max_iter, "planner.max_iter", 1)


@dataclass(frozen=True)
class SimulationSpec:
    """Closed-loop settings: integration step (s) and the longest flight allowed (s).

    ``dt`` lies in [:data:`MIN_DT`, 0.1] s and a flight has at most :data:`MAX_STEPS` steps
    (``time_limit / dt``): every step ray-casts, maps and checks collisions, so a tiny step would
    run for hours without saying why.
    """

    dt: float = 0.01
    time_limit: float = 30.0

    #: Smallest integration step (s): 0.1 ms, 10x finer than any controller here needs.
    MIN_DT: ClassVar[float] = 1e-4
    #: Most integration steps one flight may take (33 minutes of flight at the default 0.01 s).
    MAX_STEPS: ClassVar[int] = 200_000

    def __post_init__(self) -> None:
        dt = _positive(self.dt, "simulation.dt")
        if not self.MIN_DT <= dt <= 0.1:
            raise ScenarioError(f"simulation.dt: must be in [{self.MIN_DT:g}, 0.1] s (got {dt:g})")
        limit = _positive(self.time_limit, "simulation.time_limit")
        if limit / dt > self.MAX_STEPS:
            raise ScenarioError(
                f"simulation.time_limit: {limit:g} s at dt {dt:g} s is {limit / dt:.3g} steps;"
                f" at most {self.MAX_STEPS} steps per flight (raise dt or lower time_limit)"
            )


@dataclass(frozen=True)
class Scenario:
    """A complete, validated planning/simulation scenario.

    Besides each part's own checks, the whole must be consistent: start and goal lie inside the
    bounds (shrunk by the body radius) and clear of every true box; attacks name existing
    obstacles, each at most once; phantom names are new; the bounds fit in OctoMap's key range at
    the map resolution and do not span an absurd number of voxels.

    ``print(scenario)`` gives a readable summary (:meth:`summary`).
    """

    name: str
    world: World
    start: StartSpec
    goal: GoalSpec
    server_map: ServerMapSpec = field(default_factory=ServerMapSpec)
    vehicle: VehicleSpec = field(default_factory=VehicleSpec)
    camera: CameraSpec = field(default_factory=CameraSpec)
    planner: PlannerSpec = field(default_factory=PlannerSpec)
    simulation: SimulationSpec = field(default_factory=SimulationSpec)
    description: str = ""
    source: Path | None = None

    def __post_init__(self) -> None:
        _file_name(self.name, "name")
        if not isinstance(self.description, str):
            raise ScenarioError(f"description: must be a string (got {_short(self.description)})")
        if self.source is not None:
            object.__setattr__(self, "source", Path(self.source))
        self._check_map_size()
        self._check_start_goal()
        self._check_attacks()
        self._check_observed_range()

    def _check_observed_range(self) -> None:
        from secure3d.errors import ConfigError
        from secure3d.mapping.observability import observed_range

        c = self.camera
        try:
            observed_range(
                c.fx,
                c.fy,
                c.max_range,
                c.far_kind,
                self.server_map.resolution,
                min_obstacle_size=self.planner.min_obstacle_size,
                discretize=c.discretize,
                dropout=c.dropout,
                edge_allowance=self.planner.edge_allowance,
            )
        except ConfigError as exc:
            raise ScenarioError(
                f"planner.min_obstacle_size: {exc} (got {_short(self.planner.min_obstacle_size)})"
            ) from None

    def _check_map_size(self) -> None:
        b, res = self.world.bounds, self.server_map.resolution
        reach = OCTOMAP_KEY_HALF_RANGE * res
        worst = float(np.max(np.abs([b.lo, b.hi])))
        if worst >= reach:
            raise ScenarioError(
                f"world.bounds: coordinates must stay within +-{reach:g} m for an OctoMap at"
                f" resolution {res:g} m (got {worst:g} m)"
            )
        voxels = float(np.prod(b.extent)) / res**3
        if voxels > MAX_MAP_VOXELS:
            raise ScenarioError(
                f"world.bounds: the map would span {voxels:.3g} voxels at {res:g} m, more than"
                f" {MAX_MAP_VOXELS:.0e} (got extent {_fmt(b.extent)} m)"
            )

    def _check_start_goal(self) -> None:
        b = self.world.bounds
        r = self.vehicle.body_radius
        boxes = self.world.boxes
        lo = np.array([o.lo for o in boxes]).reshape(-1, 3)
        hi = np.array([o.hi for o in boxes]).reshape(-1, 3)
        for what, p in (("start", self.start.position), ("goal", self.goal.position)):
            if not b.contains(p, margin=r):
                raise ScenarioError(
                    f"{what}.position: must lie inside the world bounds shrunk by the body radius"
                    f" {r:g} m, bounds {_fmt(b.lo)}-{_fmt(b.hi)} (got {_fmt(p)})"
                )
            d = box_distance(lo, hi, p, p)
            if np.any(d < r):
                hit = boxes[int(np.argmin(d))].name
                raise ScenarioError(
                    f"{what}.position: the body (radius {r:g} m) overlaps obstacle {hit!r}"
                    f" (got {_fmt(p)})"
                )

    def _check_attacks(self) -> None:
        known = set(self.world.obstacle_names)
        for name in self.server_map.lacks:
            if name not in known:
                raise ScenarioError(
                    f"server_map.lacks: {name!r} is not an obstacle of the world"
                    f" (known: {', '.join(sorted(known)) or 'none'})"
                )
        targets: set[str] = set()
        for i, a in enumerate(self.server_map.attacks):
            where = f"server_map.attacks[{i}]"
            if a.target is not None:
                if a.target not in known:
                    raise ScenarioError(
                        f"{where}.target: not an obstacle of the world"
                        f" (got {a.target!r}; known: {', '.join(sorted(known)) or 'none'})"
                    )
                if a.target in targets:
                    raise ScenarioError(
                        f"{where}.target: each obstacle may be attacked once (got {a.target!r})"
                    )
                targets.add(a.target)
            if a.box is not None:
                if a.box.name in known:
                    raise ScenarioError(
                        f"{where}.box.name: a phantom needs a name of its own (got {a.box.name!r})"
                    )
                known.add(a.box.name)

    @property
    def hidden_obstacles(self) -> tuple[str, ...]:
        """Names of true obstacles the server does not report (hide/stale attacks, and what a
        server map file or survey lacks: ``server_map.lacks``)."""
        attacked = tuple(
            a.target
            for a in self.server_map.attacks
            if a.kind in ("hide", "stale") and a.target is not None
        )
        return attacked + tuple(n for n in self.server_map.lacks if n not in attacked)

    def summary(self, max_obstacles: int = 30) -> str:
        """A readable multi-line description (also what ``secure3d show`` prints).

        Parameters
        ----------
        max_obstacles : int
            List at most this many obstacles one per line; the rest are counted.
        """
        from secure3d.world.scenario_summary import scenario_summary

        return scenario_summary(self, max_obstacles)

    def __str__(self) -> str:
        return self.summary()
