"""The world part of a scenario: bounds, box and mesh obstacles, regions, attacks and the server
map's description (re-exported by :mod:`secure3d.world.spec`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.world.spec_fields import (
    ATTACK_KINDS,
    MAX_OBSTACLES,
    MAX_WORLD_EXTENT,
    Vec3,
    _choice,
    _fmt,
    _name,
    _positive,
    _short,
    _vec3,
)


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
    point cloud ``cloud`` (``.ply``/``.pcd``/``.xyz``, its points ray ends from ``origin``; or an
    OctoMap scan graph ``.graph``/``.log``, each scan from its own pose) or a
    mesh ``mesh`` (its surface voxelised), or ``survey``, the bytes of an OctoMap scan graph held
    in memory (what the ``survey`` campaign family makes; :func:`save_scenario` writes it beside
    the YAML as a ``.graph`` file). ``resolution`` is the voxel size of the robot's map (m).
    Region attacks apply to every source; attacks on named obstacles only to the world.
    ``lacks`` names the world's obstacles a file or survey does not hold (put there after it was
    made): hidden as a ``hide`` attack hides one from a map derived from the world, and reported
    as such when the camera first sees them.
    """

    attacks: tuple[Attack, ...] = ()
    bt: Path | None = None
    resolution: float = 0.1
    cloud: Path | None = None
    origin: Vec3 | None = None
    mesh: Path | None = None
    survey: bytes | None = None
    lacks: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "attacks", tuple(self.attacks))
        object.__setattr__(self, "lacks", tuple(self.lacks))
        if not all(isinstance(n, str) and n for n in self.lacks):
            raise ScenarioError(f"server_map.lacks: expected obstacle names (got {self.lacks!r})")
        r = _positive(self.resolution, "server_map.resolution")
        if not 0.01 <= r <= 2.0:  # finer than 1 cm or coarser than 2 m is a unit error here
            raise ScenarioError(f"server_map.resolution: must be in [0.01, 2] m (got {r})")
        if self.survey is not None and not isinstance(self.survey, bytes):
            raise ScenarioError(
                f"server_map.survey: must be a scan graph's bytes (got {type(self.survey).__name__})"
            )
        given = [k for k in ("bt", "cloud", "mesh", "survey") if getattr(self, k) is not None]
        if len(given) > 1:
            raise ScenarioError(
                f"server_map: give one of octomap, cloud, mesh (got {', '.join(given)})"
            )
        for k in given:
            if k != "survey":
                object.__setattr__(self, k, Path(getattr(self, k)))
        if self.origin is not None:
            if self.cloud is None:
                raise ScenarioError("server_map.origin: only a cloud has a sensor origin")
            object.__setattr__(self, "origin", _vec3(self.origin, "server_map.origin"))
        if self.lacks and not given:
            raise ScenarioError(
                "server_map.lacks: only a server map given as a file or survey lacks obstacles"
                " as it is; hide one from a map derived from the world with a hide attack"
                f" (got {', '.join(self.lacks)})"
            )
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

    @property
    def from_world(self) -> bool:
        """Whether the server map is the world's named obstacles with attacks (no file, no
        survey): the only source named attacks and hidden-obstacle ``hide`` attacks act on."""
        return self.source_file is None and self.survey is None
