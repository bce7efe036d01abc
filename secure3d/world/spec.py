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
import re
import reprlib
import textwrap
from collections.abc import Mapping
from dataclasses import dataclass, field
from numbers import Real
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np

from secure3d.errors import ScenarioError

Vec3 = tuple[float, float, float]

#: Largest world extent we accept along any axis (m). Bigger is almost surely a unit error
#: (millimetres) and would make the voxel map explode.
MAX_WORLD_EXTENT = 2000.0
#: Largest number of obstacles of one kind in a scenario file.
MAX_OBSTACLES = 5000
#: Largest number of voxels the robot's map may span (world volume / resolution^3). 1e9 cells is
#: e.g. 1 km x 1 km x 100 m at 10 cm: beyond that the scenario is a unit error, not a test case.
MAX_MAP_VOXELS = 1e9
#: OctoMap keys are 16 bit, centred on the origin: |coordinate| / resolution must stay below 2^15.
OCTOMAP_KEY_HALF_RANGE = 32768

VEHICLE_MODELS = ("point_mass", "quadrotor", "diff_drive")
ATTACK_KINDS = ("hide", "phantom", "shift", "stale")


#: A bounded ``repr``: nested containers are shown 3 levels and 4 items deep, so the text (and the
#: time to make it) is bounded even for a YAML alias structure that expands to billions of items.
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxstring, _REPR.maxother = 3, 80, 80
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = _REPR.maxfrozenset = 4


def _short(value: object, limit: int = 60) -> str:
    """A bounded ``repr(value)`` cut to one short line, for error messages."""
    text = " ".join(_REPR.repr(value).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _vec3(value: object, what: str) -> Vec3:
    if isinstance(value, (str, bytes)):
        raise ScenarioError(f"{what}: expected 3 numbers (got {_short(value)})")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ScenarioError(f"{what}: expected 3 numbers (got {_short(value)})") from None
    if arr.shape != (3,):
        raise ScenarioError(f"{what}: expected 3 numbers (got {_short(value)})")
    if not np.all(np.isfinite(arr)):
        raise ScenarioError(f"{what}: must be finite (got {_short(value)})")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _number(value: object, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ScenarioError(f"{what}: expected a number (got {_short(value)})")
    v = float(value)
    if not math.isfinite(v):
        raise ScenarioError(f"{what}: must be finite (got {_short(value)})")
    return v


def _positive(value: object, what: str, *, allow_zero: bool = False) -> float:
    v = _number(value, what)
    if v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ScenarioError(f"{what}: must be {bound} (got {_short(value)})")
    return v


def _integer(value: object, what: str, lo: int, hi: int | None = None) -> int:
    ok = not isinstance(value, bool) and isinstance(value, (int, np.integer))
    if not ok or value < lo or (hi is not None and value > hi):
        span = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
        raise ScenarioError(f"{what}: must be an integer {span} (got {_short(value)})")
    return int(value)


def _choice(value: object, options: tuple[str, ...], what: str) -> str:
    if value not in options:
        raise ScenarioError(f"{what}: must be one of {', '.join(options)} (got {_short(value)})")
    return str(value)


def _name(value: object, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ScenarioError(f"{what}: must be a non-empty string (got {_short(value)})")
    return value


#: A scenario's name becomes part of output file names (``<name>_secure.rrd``): letters, digits,
#: ``_``, ``-`` and ``.``, not starting with ``.`` (no path separators, no ``..``, no hidden files).
_FILE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,119}")


def _file_name(value: object, what: str) -> str:
    """``_name`` that is also safe as a file-name stem (see :data:`_FILE_NAME`)."""
    name = _name(value, what)
    if _FILE_NAME.fullmatch(name) is None:
        raise ScenarioError(
            f"{what}: must be 1-120 letters, digits, '_', '-' or '.', not starting with '.'"
            f" (it names output files; got {_short(value)})"
        )
    return name


def _fmt(v: object) -> str:
    """``(1, 2.5, 0)``: a vector printed compactly for summaries."""
    return "(" + ", ".join(f"{float(x):.3g}" for x in np.ravel(v)) + ")"


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def box_distance(lo_a: object, hi_a: object, lo_b: object, hi_b: object) -> np.ndarray:
    """Euclidean distance between axis-aligned boxes (0 when they touch or overlap).

    Parameters
    ----------
    lo_a, hi_a : (..., 3) float
        Corners of the first box(es).
    lo_b, hi_b : (..., 3) float
        Corners of the second box(es); broadcast against the first. A point is a box with lo = hi.

    Returns
    -------
    (...) float
    """
    gap = np.maximum(np.subtract(lo_b, hi_a), np.subtract(lo_a, hi_b))
    return np.linalg.norm(np.maximum(gap, 0.0), axis=-1)


@dataclass(frozen=True)
class Bounds:
    """Axis-aligned region of the world, ``lo <= p <= hi`` (m)."""

    lo: Vec3
    hi: Vec3

    def __post_init__(self) -> None:
        lo, hi = _vec3(self.lo, "world.bounds.lo"), _vec3(self.hi, "world.bounds.hi")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        ext = np.subtract(hi, lo)
        if np.any(ext <= 0):
            raise ScenarioError(
                f"world.bounds.hi: must exceed lo on every axis (got lo={lo}, hi={hi})"
            )
        if np.any(ext > MAX_WORLD_EXTENT):
            raise ScenarioError(
                f"world.bounds: extent exceeds {MAX_WORLD_EXTENT:g} m on some axis"
                f" (got {_fmt(ext)} m)"
            )

    @property
    def extent(self) -> Vec3:
        """Size along x, y, z (m)."""
        return tuple(float(e) for e in np.subtract(self.hi, self.lo))

    def contains(self, p: object, margin: float = 0.0) -> bool:
        """True if point ``p`` lies inside the bounds shrunk by ``margin``."""
        q = np.asarray(p, dtype=float)
        lo, hi = np.add(self.lo, margin), np.subtract(self.hi, margin)
        return bool(np.all(q >= lo) and np.all(q <= hi))


@dataclass(frozen=True)
class Box:
    """A named axis-aligned box obstacle, ``lo <= p <= hi`` (m)."""

    name: str
    lo: Vec3
    hi: Vec3

    def __post_init__(self) -> None:
        _name(self.name, "box.name")
        lo = _vec3(self.lo, f"box {self.name!r}.lo")
        hi = _vec3(self.hi, f"box {self.name!r}.hi")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        if np.any(np.subtract(hi, lo) <= 0):
            raise ScenarioError(
                f"box {self.name!r}.hi: must exceed lo on every axis (got lo={lo}, hi={hi})"
            )

    def shifted(self, offset: Vec3, name: str | None = None) -> Box:
        """The same box moved by ``offset``."""
        lo, hi = np.add(self.lo, offset), np.add(self.hi, offset)
        return Box(name or self.name, tuple(lo), tuple(hi))


@dataclass(frozen=True, eq=False)
class MeshObstacle:
    """A named triangle-mesh obstacle loaded from OBJ/STL/PLY.

    Attributes
    ----------
    vertices : (n, 3) float, read-only
        World coordinates: the file's vertices already scaled by ``scale`` then moved by
        ``translate``.
    faces : (m, 3) int, read-only
    path : the file it came from (None when built in Python).
    translate : (3,) float
        The translation applied to the file's vertices (m); kept so the scenario can be written
        back as YAML.
    scale : float
        The uniform scale applied to the file's vertices before ``translate``.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    path: Path | None = None
    translate: Vec3 = (0.0, 0.0, 0.0)
    scale: float = 1.0

    def __post_init__(self) -> None:
        _name(self.name, "mesh.name")
        v = np.array(self.vertices, dtype=float)
        f = np.array(self.faces, dtype=np.int64)
        if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
            raise ScenarioError(f"mesh {self.name!r}.vertices: must be (n>=4, 3) (got {v.shape})")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) < 4:
            raise ScenarioError(f"mesh {self.name!r}.faces: must be (m>=4, 3) (got {f.shape})")
        if not np.all(np.isfinite(v)):
            raise ScenarioError(f"mesh {self.name!r}.vertices: contain NaN or inf")
        if f.min() < 0 or f.max() >= len(v):
            raise ScenarioError(
                f"mesh {self.name!r}.faces: index out of range [0, {len(v)})"
                f" (got {f.min()}..{f.max()})"
            )
        v.flags.writeable = False
        f.flags.writeable = False
        object.__setattr__(self, "vertices", v)
        object.__setattr__(self, "faces", f)
        translate = _vec3(self.translate, f"mesh {self.name!r}.translate")
        object.__setattr__(self, "translate", translate)
        object.__setattr__(self, "scale", _positive(self.scale, f"mesh {self.name!r}.scale"))
        if self.path is not None:
            object.__setattr__(self, "path", Path(self.path))

    @property
    def lo(self) -> Vec3:
        return tuple(float(x) for x in self.vertices.min(axis=0))

    @property
    def hi(self) -> Vec3:
        return tuple(float(x) for x in self.vertices.max(axis=0))

    def shifted(self, offset: Vec3, name: str | None = None) -> MeshObstacle:
        """The same mesh moved by ``offset``."""
        return MeshObstacle(
            name or self.name,
            self.vertices + np.asarray(offset, dtype=float),
            self.faces,
            self.path,
            tuple(np.add(self.translate, offset)),
            self.scale,
        )


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
        n = len(self.boxes) + len(self.meshes)
        if n > MAX_OBSTACLES:
            raise ScenarioError(f"world: at most {MAX_OBSTACLES} obstacles (got {n})")
        names = [o.name for o in (*self.boxes, *self.meshes)]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ScenarioError(f"world: obstacle names must be unique (got repeated {dup})")
        if self.octomap is not None:
            object.__setattr__(self, "octomap", Path(self.octomap))

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
class Region:
    """An axis-aligned region of a server map, ``lo <= p <= hi`` (m): what a region attack edits."""

    lo: Vec3
    hi: Vec3

    def __post_init__(self) -> None:
        lo, hi = _vec3(self.lo, "attack.region.lo"), _vec3(self.hi, "attack.region.hi")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        if np.any(np.subtract(hi, lo) <= 0):
            raise ScenarioError(
                f"attack.region.hi: must exceed lo on every axis (got lo={lo}, hi={hi})"
            )


@dataclass(frozen=True)
class Attack:
    """One tampering of the server map.

    kind
        ``hide``: obstacle ``target`` is deleted from the server map (the dangerous case);
        ``phantom``: ``box`` is added although it does not exist;
        ``shift``: obstacle ``target`` is reported moved by ``offset`` (m);
        ``stale``: obstacle ``target`` appeared after the map was made (reported absent).

    A *region attack* names a ``region`` instead of an obstacle and acts on any server map (an
    OctoMap file, a point cloud, a mesh, or the world's named obstacles), voxel by voxel:
    ``hide`` reports every voxel whose centre lies in the region free, ``shift`` moves the
    region's claimed-occupied voxels by ``offset`` (rounded to whole voxels) and reports the
    voxels they left free, ``phantom`` claims every voxel the region touches occupied.
    """

    kind: Literal["hide", "phantom", "shift", "stale"]
    target: str | None = None
    box: Box | None = None
    offset: Vec3 | None = None
    region: Region | None = None

    def __post_init__(self) -> None:
        _choice(self.kind, ATTACK_KINDS, "attack.kind")
        if self.region is not None:
            self._check_region()
            return
        if self.kind in ("hide", "shift", "stale"):
            _name(self.target, f"attack {self.kind!r}.target")
        elif self.target is not None:
            raise ScenarioError(
                f"attack 'phantom'.target: a phantom has no target (got {self.target!r})"
            )
        if self.kind == "phantom" and not isinstance(self.box, Box):
            raise ScenarioError(f"attack 'phantom'.box: needs a Box (got {_short(self.box)})")
        if self.kind != "phantom" and self.box is not None:
            raise ScenarioError(f"attack {self.kind!r}.box: only a phantom has a box")
        self._check_offset()

    def _check_offset(self) -> None:
        if self.kind == "shift":
            if self.offset is None:
                raise ScenarioError("attack 'shift'.offset: missing (a shift needs an offset)")
            object.__setattr__(self, "offset", _vec3(self.offset, "attack 'shift'.offset"))
        elif self.offset is not None:
            raise ScenarioError(f"attack {self.kind!r}.offset: only a shift has an offset")

    def _check_region(self) -> None:
        if not isinstance(self.region, Region):
            raise ScenarioError(f"attack.region: needs a Region (got {_short(self.region)})")
        if self.kind == "stale":
            raise ScenarioError("attack 'stale'.region: a region attack is hide, shift or phantom")
        if self.target is not None or self.box is not None:
            raise ScenarioError(
                f"attack {self.kind!r}.region: a region attack has no target or box"
                f" (got target={self.target!r})"
            )
        self._check_offset()

    def describe(self) -> str:
        """One phrase such as ``"shift shelf_3 by (0.5, 0, 0)"``."""
        if self.region is not None:
            where = f"region {_fmt(self.region.lo)}-{_fmt(self.region.hi)}"
            by = f" by {_fmt(self.offset)}" if self.kind == "shift" else ""
            return f"{self.kind} {where}{by}"
        if self.kind == "phantom":
            return f"phantom {self.box.name} {_fmt(self.box.lo)}-{_fmt(self.box.hi)}"
        if self.kind == "shift":
            return f"shift {self.target} by {_fmt(self.offset)}"
        return f"{self.kind} {self.target}"


@dataclass(frozen=True)
class ServerMapSpec:
    """What the (untrusted) map server claims.

    One source: derived from the true world with ``attacks`` applied (no file), or its own
    OctoMap file ``bt`` (``.bt`` or ``.ot``; the YAML key is ``octomap``, ``bt`` still works), a
    point cloud ``cloud`` (``.ply``/``.pcd``/``.xyz``, its points ray ends from ``origin``) or a
    mesh ``mesh`` (its surface voxelised). ``resolution`` is the voxel size of the robot's map
    (m). Region attacks apply to every source; attacks on named obstacles only to the world.
    """

    attacks: tuple[Attack, ...] = ()
    bt: Path | None = None
    resolution: float = 0.1
    cloud: Path | None = None
    origin: Vec3 | None = None
    mesh: Path | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "attacks", tuple(self.attacks))
        r = _positive(self.resolution, "server_map.resolution")
        if not 0.01 <= r <= 2.0:  # finer than 1 cm or coarser than 2 m is a unit error here
            raise ScenarioError(f"server_map.resolution: must be in [0.01, 2] m (got {r})")
        given = [k for k in ("bt", "cloud", "mesh") if getattr(self, k) is not None]
        if len(given) > 1:
            raise ScenarioError(
                f"server_map: give one of octomap, cloud, mesh (got {', '.join(given)})"
            )
        for k in given:
            object.__setattr__(self, k, Path(getattr(self, k)))
        if self.origin is not None:
            if self.cloud is None:
                raise ScenarioError("server_map.origin: only a cloud has a sensor origin")
            object.__setattr__(self, "origin", _vec3(self.origin, "server_map.origin"))
        named = [a for a in self.attacks if a.region is None]
        if given and named:
            raise ScenarioError(
                f"server_map.attacks: only region attacks act on a server map given as a"
                f" {given[0]} file (got {named[0].describe()!r})"
            )

    @property
    def octomap(self) -> Path | None:
        """The server's OctoMap file (``.bt`` or ``.ot``), if it is one."""
        return self.bt

    @property
    def source_file(self) -> Path | None:
        """The server map's own file (OctoMap, cloud or mesh), None when derived from the world."""
        return self.bt or self.cloud or self.mesh


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
        so those scenarios plan as before (0.1 m cuts their view to 5.6 m: blind corner T 4.17 ->
        4.12 s, forest 4.565 -> 4.573 s).
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
        """Names of true obstacles the server does not report (hide/stale attacks)."""
        return tuple(
            a.target
            for a in self.server_map.attacks
            if a.kind in ("hide", "stale") and a.target is not None
        )

    def summary(self, max_obstacles: int = 30) -> str:
        """A readable multi-line description (also what ``secure3d show`` prints).

        Parameters
        ----------
        max_obstacles : int
            List at most this many obstacles one per line; the rest are counted.
        """
        w, b, v, c, p = self.world, self.world.bounds, self.vehicle, self.camera, self.planner
        status: dict[str, str] = {}
        for a in self.server_map.attacks:
            if a.target is None:
                continue
            if a.kind in ("hide", "stale"):
                status[a.target] = f"HIDDEN by the server ({a.kind})"
            elif a.kind == "shift":
                status[a.target] = f"SHIFTED by the server by {_fmt(a.offset)} m"
        rows = [(o.name, "box", o.lo, o.hi, status.get(o.name, "")) for o in w.boxes]
        rows += [
            (
                o.name,
                f"mesh {o.path.name if o.path else '(inline)'}",
                o.lo,
                o.hi,
                status.get(o.name, ""),
            )
            for o in w.meshes
        ]
        rows += [
            (a.box.name, "box", a.box.lo, a.box.hi, "PHANTOM: claimed by the server, not real")
            for a in self.server_map.attacks
            if a.kind == "phantom" and a.box is not None
        ]
        width = max([len(r[0]) for r in rows] + [4])
        kind_width = max([len(r[1]) for r in rows] + [3])
        out = [f"Scenario {self.name!r}" + (f"  ({self.source})" if self.source else "")]
        text = " ".join(self.description.split()) or "(no description)"
        out += textwrap.wrap(text, 96, initial_indent="  purpose   : ", subsequent_indent=" " * 14)
        ext = b.extent
        out.append(
            f"  world     : {ext[0]:g} x {ext[1]:g} x {ext[2]:g} m, bounds {_fmt(b.lo)} -"
            f" {_fmt(b.hi)}; {_count(len(w.boxes), 'box', 'boxes')},"
            f" {_count(len(w.meshes), 'mesh', 'meshes')}"
            + (f", octomap {w.octomap.name}" if w.octomap else "")
        )
        voxels = f", plus the occupied voxels of {w.octomap.name}" if w.octomap else ""
        out.append(f"  obstacles : {len(rows)} named (true and claimed){voxels}")
        for name, kind, lo, hi, note in rows[:max_obstacles]:
            line = f"    {name:<{width}}  {kind:<{kind_width}}  {_fmt(lo)} - {_fmt(hi)}"
            out.append(f"{line}  {note}" if note else line)
        if len(rows) > max_obstacles:
            out.append(f"    ... and {len(rows) - max_obstacles} more")
        s = self.server_map
        if s.source_file is not None:
            kind = "OctoMap" if s.bt else ("point cloud" if s.cloud else "mesh")
            claim = f"given as its own {kind} {s.source_file.name}"
            if s.attacks:
                claim += "; attacks: " + "; ".join(a.describe() for a in s.attacks)
        else:
            claim = "the truth with attacks: " + (
                "; ".join(a.describe() for a in s.attacks) if s.attacks else "none (honest)"
            )
        out.append(f"  server map: resolution {s.resolution:g} m, {claim}")
        lim = ", ".join(f"{k}={val:g}" for k, val in sorted(v.limits.items())) or "model defaults"
        out.append(f"  vehicle   : {v.model}, body radius {v.body_radius:g} m, limits: {lim}")
        vfov = math.degrees(c.vfov)
        out.append(
            f"  camera    : {c.width}x{c.height} px, hfov {c.hfov_deg:g} deg, vfov {vfov:.3g} deg,"
            f" {c.far_kind} limit {c.max_range:g} m, {c.rate_hz:g} Hz,"
            f" pitch {c.mount_pitch_deg:g} deg, offset {_fmt(c.mount_offset)} m"
            + (f", noise {c.noise_std:g} m" if c.noise_std else "")
            + (f", dropout {c.dropout:g}" if c.dropout else "")
        )
        st, g = self.start, self.goal
        dist = float(np.linalg.norm(np.subtract(g.position, st.position)))
        out.append(
            f"  start     : {_fmt(st.position)} m, velocity {_fmt(st.velocity)} m/s,"
            f" yaw {math.degrees(st.yaw):.3g} deg"
        )
        out.append(
            f"  goal      : {_fmt(g.position)} m +- {g.tolerance:g} m"
            f" ({dist:.3g} m from the start in a straight line)"
        )
        look = f"{p.lookback} look-back" + (
            f" ({p.lookback_steps} steps)" if p.lookback == "fixed" else ""
        )
        out.append(
            f"  planner   : {p.nodes} nodes, {look}, {p.solver}, {p.reactive_family} reactive sets,"
            f" {p.controller} controller, margin {p.margin:g} m, max {p.max_iter} iterations"
        )
        sim = self.simulation
        out.append(f"  simulation: dt {sim.dt:g} s, time limit {sim.time_limit:g} s")
        wrapped = [
            "\n".join(textwrap.wrap(line, 100, subsequent_indent=" " * 14))
            if len(line) > 100
            else line
            for line in out
        ]
        return "\n".join(wrapped)

    def __str__(self) -> str:
        return self.summary()
