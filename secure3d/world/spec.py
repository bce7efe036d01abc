"""The scenario data model: frozen, validated dataclasses.

A :class:`Scenario` is what ``maps/*.yaml`` describes and what every other layer consumes: the true
world (seen only by the simulator), the server's claim about it (with attacks), the vehicle, the
camera, start, goal and planner settings. Loading and validating YAML lives in
:mod:`secure3d.world.scenario`; this module only defines the types and their invariants, so it can
be used to build scenarios in Python too::

    Scenario(name="demo", world=World(bounds=Bounds((0, 0, 0), (10, 10, 3)), boxes=(...)), ...)

Units are SI (metres, seconds, radians unless a field says degrees). Frames: world is z-up.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from secure3d.errors import ScenarioError

Vec3 = tuple[float, float, float]

#: Largest world extent we accept along any axis (m). Bigger is almost surely a unit error
#: (millimetres) and would make the voxel map explode.
MAX_WORLD_EXTENT = 2000.0
#: Largest number of obstacles of one kind in a scenario file.
MAX_OBSTACLES = 5000

VEHICLE_MODELS = ("point_mass", "quadrotor", "diff_drive")
ATTACK_KINDS = ("hide", "phantom", "shift", "stale")


def _vec3(value: object, what: str) -> Vec3:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ScenarioError(f"{what}: expected 3 numbers, got {value!r}") from None
    if arr.shape != (3,):
        raise ScenarioError(f"{what}: expected 3 numbers, got {value!r}")
    if not np.all(np.isfinite(arr)):
        raise ScenarioError(f"{what}: must be finite, got {value!r}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _positive(value: float, what: str, *, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ScenarioError(f"{what}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ScenarioError(f"{what}: must be finite and {bound}, got {value!r}")
    return v


@dataclass(frozen=True)
class Bounds:
    """Axis-aligned region of the world, ``lo <= p <= hi`` (m)."""

    lo: Vec3
    hi: Vec3

    def __post_init__(self) -> None:
        lo, hi = _vec3(self.lo, "bounds.lo"), _vec3(self.hi, "bounds.hi")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        ext = np.subtract(hi, lo)
        if np.any(ext <= 0):
            raise ScenarioError(f"bounds: hi must exceed lo on every axis, got lo={lo} hi={hi}")
        if np.any(ext > MAX_WORLD_EXTENT):
            raise ScenarioError(f"bounds: extent {tuple(ext)} exceeds {MAX_WORLD_EXTENT} m")

    def contains(self, p: object, margin: float = 0.0) -> bool:
        """True if point ``p`` lies inside the bounds shrunk by ``margin``."""
        q = np.asarray(p, dtype=float)
        return bool(np.all(q >= np.add(self.lo, margin)) and np.all(q <= np.subtract(self.hi, margin)))


@dataclass(frozen=True)
class Box:
    """A named axis-aligned box obstacle, ``lo <= p <= hi`` (m)."""

    name: str
    lo: Vec3
    hi: Vec3

    def __post_init__(self) -> None:
        lo = _vec3(self.lo, f"box {self.name!r}.lo")
        hi = _vec3(self.hi, f"box {self.name!r}.hi")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        if np.any(np.subtract(hi, lo) <= 0):
            raise ScenarioError(f"box {self.name!r}: hi must exceed lo, got lo={lo} hi={hi}")

    def shifted(self, offset: Vec3, name: str | None = None) -> Box:
        """The same box moved by ``offset``."""
        return Box(name or self.name, tuple(np.add(self.lo, offset)), tuple(np.add(self.hi, offset)))


@dataclass(frozen=True, eq=False)
class MeshObstacle:
    """A named triangle-mesh obstacle loaded from OBJ/STL/PLY.

    Attributes
    ----------
    vertices : (n, 3) float, read-only
    faces : (m, 3) int, read-only
    path : the file it came from (None when built in Python).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    path: Path | None = None

    def __post_init__(self) -> None:
        v = np.array(self.vertices, dtype=float)
        f = np.array(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
            raise ScenarioError(f"mesh {self.name!r}: vertices must be (n>=4, 3), got {v.shape}")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 4:
            raise ScenarioError(f"mesh {self.name!r}: faces must be (m>=4, 3), got {f.shape}")
        if not np.all(np.isfinite(v)):
            raise ScenarioError(f"mesh {self.name!r}: vertices contain NaN or inf")
        if f.min() < 0 or f.max() >= len(v):
            raise ScenarioError(f"mesh {self.name!r}: face index out of range [0, {len(v)})")
        v.flags.writeable = False
        f.flags.writeable = False
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)

    @property
    def lo(self) -> Vec3:
        return tuple(self.vertices.min(axis=0))

    @property
    def hi(self) -> Vec3:
        return tuple(self.vertices.max(axis=0))

    def shifted(self, offset: Vec3, name: str | None = None) -> MeshObstacle:
        return MeshObstacle(name or self.name, self.vertices + np.asarray(offset), self.faces, self.path)


@dataclass(frozen=True)
class World:
    """The true world: bounds plus obstacles. ``octomap`` adds the occupied voxels of a ``.bt``."""

    bounds: Bounds
    boxes: tuple[Box, ...] = ()
    meshes: tuple[MeshObstacle, ...] = ()
    octomap: Path | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "boxes", tuple(self.boxes))
        object.__setattr__(self, "meshes", tuple(self.meshes))
        if len(self.boxes) + len(self.meshes) > MAX_OBSTACLES:
            raise ScenarioError(f"world: more than {MAX_OBSTACLES} obstacles")
        names = [o.name for o in (*self.boxes, *self.meshes)]
        dup = {n for n in names if names.count(n) > 1}
        if dup:
            raise ScenarioError(f"world: obstacle names must be unique, repeated: {sorted(dup)}")

    def obstacle(self, name: str) -> Box | MeshObstacle:
        """The obstacle called ``name``; ``ScenarioError`` if there is none."""
        for o in (*self.boxes, *self.meshes):
            if o.name == name:
                return o
        raise ScenarioError(f"world: no obstacle named {name!r}")

    @property
    def obstacle_names(self) -> tuple[str, ...]:
        return tuple(o.name for o in (*self.boxes, *self.meshes))


@dataclass(frozen=True)
class Attack:
    """One tampering of the server map.

    kind
        ``hide``: obstacle ``target`` is deleted from the server map (the dangerous case);
        ``phantom``: ``box`` is added although it does not exist;
        ``shift``: obstacle ``target`` is reported moved by ``offset``;
        ``stale``: obstacle ``target`` appeared after the map was made (reported absent).
    """

    kind: Literal["hide", "phantom", "shift", "stale"]
    target: str | None = None
    box: Box | None = None
    offset: Vec3 | None = None

    def __post_init__(self) -> None:
        if self.kind not in ATTACK_KINDS:
            raise ScenarioError(f"attack.kind: must be one of {ATTACK_KINDS}, got {self.kind!r}")
        if self.kind in ("hide", "shift", "stale") and not self.target:
            raise ScenarioError(f"attack {self.kind!r}: needs a 'target' obstacle name")
        if self.kind == "phantom" and self.box is None:
            raise ScenarioError("attack 'phantom': needs a 'box'")
        if self.kind == "shift":
            if self.offset is None:
                raise ScenarioError("attack 'shift': needs an 'offset'")
            object.__setattr__(self, "offset", _vec3(self.offset, "attack.offset"))


@dataclass(frozen=True)
class ServerMapSpec:
    """What the (untrusted) map server claims.

    Either derived from the true world with ``attacks`` applied (``bt is None``), or given as its own
    OctoMap file ``bt``. ``resolution`` is the voxel size of the robot's map (m).
    """

    attacks: tuple[Attack, ...] = ()
    bt: Path | None = None
    resolution: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "attacks", tuple(self.attacks))
        r = _positive(self.resolution, "server_map.resolution")
        if not 0.01 <= r <= 2.0:  # finer than 1 cm or coarser than 2 m is a unit error here
            raise ScenarioError(f"server_map.resolution: must be in [0.01, 2] m, got {r}")


@dataclass(frozen=True)
class VehicleSpec:
    """The vehicle: model name, body radius (m) and model-specific limits.

    ``limits`` maps field names of the model's limits dataclass (see :mod:`secure3d.dynamics`) to
    values; it is validated by the dynamics module when the model is built.
    """

    model: str = "point_mass"
    body_radius: float = 0.2
    limits: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.model not in VEHICLE_MODELS:
            raise ScenarioError(f"vehicle.model: must be one of {VEHICLE_MODELS}, got {self.model!r}")
        r = _positive(self.body_radius, "vehicle.body_radius")
        if r > 5.0:
            raise ScenarioError(f"vehicle.body_radius: {r} m is absurd (> 5 m)")
        object.__setattr__(self, "limits", dict(self.limits))

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

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 8 <= v <= 4096:
                raise ScenarioError(f"camera.{name}: must be an integer in [8, 4096], got {v!r}")
        h = _positive(self.hfov_deg, "camera.hfov_deg")
        if not h < 170:
            raise ScenarioError(f"camera.hfov_deg: must be < 170 for a pinhole camera, got {h}")
        if self.vfov_deg is not None:
            v = _positive(self.vfov_deg, "camera.vfov_deg")
            if not v < 170:
                raise ScenarioError(f"camera.vfov_deg: must be < 170, got {v}")
        _positive(self.max_range, "camera.max_range")
        if self.far_kind not in ("depth", "range"):
            raise ScenarioError(f"camera.far_kind: must be 'depth' or 'range', got {self.far_kind!r}")
        _positive(self.rate_hz, "camera.rate_hz")
        if not -89 <= float(self.mount_pitch_deg) <= 89:
            raise ScenarioError(f"camera.mount_pitch_deg: must be in [-89, 89], got {self.mount_pitch_deg}")
        object.__setattr__(self, "mount_offset", _vec3(self.mount_offset, "camera.mount_offset"))
        _positive(self.noise_std, "camera.noise_std", allow_zero=True)
        if not 0 <= float(self.dropout) < 1:
            raise ScenarioError(f"camera.dropout: must be in [0, 1), got {self.dropout}")

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
        if not math.isfinite(float(self.yaw)):
            raise ScenarioError(f"start.yaw: must be finite, got {self.yaw!r}")


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
    """

    nodes: int = 40
    lookback: Literal["adaptive", "fixed"] = "adaptive"
    lookback_steps: int = 3
    solver: Literal["ipopt", "fatrop"] = "ipopt"
    reactive_family: Literal["fitted", "closed_form"] = "fitted"
    controller: Literal["braking", "mpc"] = "braking"
    margin: float = 0.02
    max_iter: int = 500

    def __post_init__(self) -> None:
        if isinstance(self.nodes, bool) or not isinstance(self.nodes, int) or not 5 <= self.nodes <= 400:
            raise ScenarioError(f"planner.nodes: must be an integer in [5, 400], got {self.nodes!r}")
        if self.lookback not in ("adaptive", "fixed"):
            raise ScenarioError(f"planner.lookback: must be 'adaptive' or 'fixed', got {self.lookback!r}")
        if not isinstance(self.lookback_steps, int) or not 1 <= self.lookback_steps < self.nodes:
            raise ScenarioError(f"planner.lookback_steps: must be in [1, nodes), got {self.lookback_steps!r}")
        if self.solver not in ("ipopt", "fatrop"):
            raise ScenarioError(f"planner.solver: must be 'ipopt' or 'fatrop', got {self.solver!r}")
        if self.reactive_family not in ("fitted", "closed_form"):
            raise ScenarioError(
                f"planner.reactive_family: must be 'fitted' or 'closed_form', got {self.reactive_family!r}"
            )
        if self.controller not in ("braking", "mpc"):
            raise ScenarioError(f"planner.controller: must be 'braking' or 'mpc', got {self.controller!r}")
        _positive(self.margin, "planner.margin", allow_zero=True)
        if not isinstance(self.max_iter, int) or self.max_iter < 1:
            raise ScenarioError(f"planner.max_iter: must be a positive integer, got {self.max_iter!r}")


@dataclass(frozen=True)
class SimulationSpec:
    """Closed-loop settings: integration step (s) and the longest flight allowed (s)."""

    dt: float = 0.01
    time_limit: float = 30.0

    def __post_init__(self) -> None:
        dt = _positive(self.dt, "simulation.dt")
        if dt > 0.1:
            raise ScenarioError(f"simulation.dt: must be <= 0.1 s, got {dt}")
        _positive(self.time_limit, "simulation.time_limit")


@dataclass(frozen=True)
class Scenario:
    """A complete, validated planning/simulation scenario."""

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
        b = self.world.bounds
        r = self.vehicle.body_radius
        if not b.contains(self.start.position, margin=r):
            raise ScenarioError(f"start.position {self.start.position} is not inside the world bounds")
        if not b.contains(self.goal.position, margin=r):
            raise ScenarioError(f"goal.position {self.goal.position} is not inside the world bounds")
        known = set(self.world.obstacle_names)
        for a in self.server_map.attacks:
            if a.target is not None and a.target not in known:
                raise ScenarioError(
                    f"server_map.attacks: {a.kind} targets {a.target!r}, which is not an obstacle"
                    f" of the world (known: {sorted(known)})"
                )

    @property
    def hidden_obstacles(self) -> tuple[str, ...]:
        """Names of true obstacles the server does not report (hide/stale attacks)."""
        return tuple(a.target for a in self.server_map.attacks if a.kind in ("hide", "stale"))
