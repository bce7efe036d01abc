"""Scenario files (``maps/*.yaml``) to validated :class:`~secure3d.world.spec.Scenario` objects.

The schema is documented with a full annotated example in ``maps/README.md``. Loading is strict,
because a scenario that silently means something else than its author wrote makes every later
experiment wrong:

- the file is read with ``yaml.safe_load`` semantics (plus: duplicate keys and non-string keys are
  refused), and files over 1 MB are refused before parsing;
- every section accepts only its known keys (a typo such as ``vehical:`` is an error naming the key
  and suggesting the right one), required keys must be present, every value has the right type,
  and numbers must be finite (YAML ``.nan`` / ``.inf`` are refused);
- mesh and ``.bt`` paths are relative to the YAML file's folder and must resolve inside it;
- absurd sizes (world extent, obstacle counts, voxel counts, camera resolution) are refused;
- the vehicle limits are validated by building the dynamics model.

Every problem raises one :class:`~secure3d.errors.ScenarioError` whose message is a single line
``"<file>: <field path>: <problem> (got <value>)"``, e.g.
``"maps/x.yaml: world.boxes[2].lo: must be finite (got [0, nan, 1])"``.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import os
import re
import types
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Literal, Union, get_args, get_origin, get_type_hints

import numpy as np
import yaml

from secure3d.errors import ConfigError, ScenarioError
from secure3d.world import spec
from secure3d.world.attacks import octomap_voxel_boxes
from secure3d.world.bundled import resolve_scenario
from secure3d.world.meshes import load_mesh, mesh_from_arrays, resolve_inside
from secure3d.world.placement import check_start_goal_clear
from secure3d.world.server_sources import check_source_file
from secure3d.world.spec import (
    ATTACK_KINDS,
    MAX_OBSTACLES,
    MAX_WORLD_EXTENT,
    Attack,
    Bounds,
    Box,
    CameraSpec,
    GoalSpec,
    MeshObstacle,
    PlannerSpec,
    Region,
    Scenario,
    ServerMapSpec,
    SimulationSpec,
    StartSpec,
    VehicleSpec,
    World,
    box_distance,
)

__all__ = [
    "MAX_SCENARIO_BYTES",
    "load_scenario",
    "save_scenario",
    "scenario_from_dict",
    "scenario_to_dict",
]

#: Largest scenario file we parse (bytes). Real scenarios are a few kB; anything near 1 MB is a
#: mistake (or an attempt to make the YAML parser work hard).
MAX_SCENARIO_BYTES = 1_000_000
#: Most values a scenario may hold once its YAML aliases are expanded. Aliases share one object,
#: so a few hundred bytes can stand for billions of values (an "alias bomb"), which any later
#: walk over them (validation, an error message, a copy) would expand.
MAX_EXPANDED_VALUES = 100_000

_TOP_KEYS = (
    "name",
    "description",
    "world",
    "server_map",
    "vehicle",
    "camera",
    "start",
    "goal",
    "planner",
    "simulation",
)
_REQUIRED_TOP = ("name", "world", "start", "goal")


class _FieldError(Exception):
    """A problem at one field path; turned into a ScenarioError with the file name prefixed."""

    def __init__(self, path: str, problem: str, value: object = dataclasses.MISSING) -> None:
        self.path, self.problem, self.value = path, problem, value
        super().__init__(self.line())

    def line(self) -> str:
        got = "" if self.value is dataclasses.MISSING else f" (got {spec._short(self.value)})"
        return f"{self.path}: {self.problem}{got}"


# --------------------------------------------------------------------------------------------
# YAML reading
# --------------------------------------------------------------------------------------------


class _StrictLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
    """SafeLoader that refuses duplicate and non-string mapping keys (PyYAML keeps the last);
    libyaml's parser when PyYAML has it (5x faster)."""


def _construct_mapping(loader: _StrictLoader, node: yaml.MappingNode) -> dict[str, Any]:
    loader.flatten_mapping(node)
    out: dict[str, Any] = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if not isinstance(key, str):
            raise yaml.constructor.ConstructorError(
                None, None, f"mapping keys must be strings (got {key!r})", key_node.start_mark
            )
        if key in out:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark
            )
        out[key] = loader.construct_object(value_node, deep=True)
    return out


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _read_yaml(path: Path, label: str) -> object:
    if not path.exists():
        raise ScenarioError(f"{label}: no such file")
    if not path.is_file():
        raise ScenarioError(f"{label}: not a regular file")
    try:
        size = path.stat().st_size
        if size > MAX_SCENARIO_BYTES:
            raise ScenarioError(
                f"{label}: scenario files must be at most {MAX_SCENARIO_BYTES} bytes"
                f" (got {size} bytes)"
            )
        with path.open("rb") as fh:
            raw = fh.read(MAX_SCENARIO_BYTES + 1)
    except OSError as exc:
        raise ScenarioError(f"{label}: cannot read: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{label}: not UTF-8 text (bad byte at offset {exc.start})") from None
    try:
        data = yaml.load(text, Loader=_StrictLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = " ".join(str(exc.problem or exc.context or "invalid YAML").split())
        raise ScenarioError(f"{label}: {where}YAML error: {problem}") from None
    except (yaml.YAMLError, RecursionError, ValueError) as exc:  # ValueError: int() limits
        detail = " ".join(str(exc).split())[:120] or type(exc).__name__
        raise ScenarioError(f"{label}: YAML error: {detail}") from None
    why = _expansion_problem(data, MAX_EXPANDED_VALUES)
    if why is not None:
        raise ScenarioError(f"{label}: {why}")
    return data


def _expansion_problem(data: object, limit: int) -> str | None:
    """Why ``data`` is unsafe to walk: more than ``limit`` values once aliases are expanded, or
    an alias that contains itself. Counts each shared object once (memo by id), so the check
    costs the size of the file, not of the expansion."""
    sizes: dict[int, int] = {}
    stack: list[tuple[object, bool]] = [(data, False)]
    open_: set[int] = set()
    while stack:
        node, done = stack.pop()
        if not isinstance(node, (dict, list)):
            continue
        key = id(node)
        children = list(node.keys()) + list(node.values()) if isinstance(node, dict) else node
        if done:
            open_.discard(key)
            total = 1 + sum(sizes.get(id(c), 1) for c in children)
            sizes[key] = total
            if total > limit:
                return f"too many values once YAML aliases are expanded (over {limit})"
            continue
        if key in sizes:
            continue
        if key in open_:
            return "a YAML alias refers to a value that contains it"
        open_.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in children if isinstance(c, (dict, list)))
    return None


# --------------------------------------------------------------------------------------------
# Typed field readers (each raises _FieldError with the field path)
# --------------------------------------------------------------------------------------------


def _as_mapping(value: object, path: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _FieldError(path, "expected a mapping (key: value, ...)", value)
    return value


def _as_list(value: object, path: str, limit: int = MAX_OBSTACLES) -> list[Any]:
    if value is None:
        return []
    if not isinstance(value, list):
        raise _FieldError(path, "expected a list", value)
    if len(value) > limit:
        raise _FieldError(path, f"at most {limit} entries allowed", f"{len(value)} entries")
    return value


def _check_keys(
    data: Mapping[str, Any], allowed: tuple[str, ...], required: tuple[str, ...], path: str
) -> None:
    prefix = f"{path}." if path else ""
    for key in data:
        if key not in allowed:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            # a key with line breaks or edge blanks is quoted: the error stays one readable line
            plain = isinstance(key, str) and key.isprintable() and key == key.strip() != ""
            raise _FieldError(
                f"{prefix}{key if plain else repr(key)}",
                f"unknown key; {hint}allowed keys: {', '.join(sorted(allowed))}",
            )
    for key in required:
        if key not in data:
            raise _FieldError(f"{prefix}{key}", "missing required field")


def _as_float(value: object, path: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        hint = ""
        if isinstance(value, str):
            try:
                float(value)
                hint = " (YAML 1.1 reads exponents without a dot as text: write 1.0e3)"
            except ValueError:
                pass
        raise _FieldError(path, f"expected a number{hint}", value)
    if not _finite(value):
        raise _FieldError(path, "must be a finite number", value)
    return float(value)


def _finite(value: int | float) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond the float range
        return False


def _as_int(value: object, path: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise _FieldError(path, "expected an integer", value)
    return value


def _as_bool(value: object, path: str) -> bool:
    if not isinstance(value, bool):
        raise _FieldError(path, "expected true or false", value)
    return value


def _as_str(value: object, path: str) -> str:
    if not isinstance(value, str):
        raise _FieldError(path, "expected a string", value)
    return value


def _as_name(value: object, path: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise _FieldError(path, "expected a non-empty name", value)
    return value


def _as_vec3(value: object, path: str) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise _FieldError(path, "expected a list of 3 numbers", value)
    for i, x in enumerate(value):
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            raise _FieldError(f"{path}[{i}]", "expected a number", x)
        if not _finite(x):
            raise _FieldError(path, "must be finite", value)
    return (float(value[0]), float(value[1]), float(value[2]))


def _as_limits(value: object, path: str) -> dict[str, float]:
    data = _as_mapping(value if value is not None else {}, path)
    return {k: _as_float(v, f"{path}.{k}") for k, v in data.items()}


def _reader(hint: object) -> Callable[[object, str], object]:
    """Map a dataclass field's type hint to the reader that checks a YAML value against it."""
    if hint is int:
        return _as_int
    if hint is float:
        return _as_float
    if hint is str:
        return _as_str
    if hint is bool:
        return _as_bool
    if hint == spec.Vec3:
        return _as_vec3
    origin, args = get_origin(hint), get_args(hint)
    if origin is Literal:

        def read_choice(value: object, path: str) -> object:
            if value not in args:
                raise _FieldError(path, f"must be one of {', '.join(map(str, args))}", value)
            return value

        return read_choice
    if origin in (Union, types.UnionType) and type(None) in args:
        (inner,) = [a for a in args if a is not type(None)]
        read = _reader(inner)
        return lambda value, path: None if value is None else read(value, path)
    if origin is Mapping:
        return _as_limits
    if origin is tuple and args == (float, Ellipsis):
        return lambda value, path: tuple(
            _as_float(v, f"{path}[{i}]") for i, v in enumerate(_as_list(value, path, 16))
        )
    raise TypeError(f"no YAML reader for type hint {hint!r}")  # a new spec field needs one


def _flat_section(cls: type, data: object, path: str) -> dict[str, Any]:
    """Check a section whose keys are exactly the fields of dataclass ``cls``; return kwargs."""
    data = _as_mapping(data if data is not None else {}, path)
    fields = dataclasses.fields(cls)
    hints = get_type_hints(cls, vars(spec))
    required = tuple(
        f.name
        for f in fields
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    )
    _check_keys(data, tuple(f.name for f in fields), required, path)
    return {k: _reader(hints[k])(v, f"{path}.{k}") for k, v in data.items()}


# --------------------------------------------------------------------------------------------
# Sections
# --------------------------------------------------------------------------------------------


def _box(data: object, path: str, bounds: Bounds) -> Box:
    data = _as_mapping(data, path)
    _check_keys(data, ("name", "lo", "hi"), ("name", "lo", "hi"), path)
    name = _as_name(data["name"], f"{path}.name")
    lo, hi = _as_vec3(data["lo"], f"{path}.lo"), _as_vec3(data["hi"], f"{path}.hi")
    if np.any(np.subtract(hi, lo) <= 0):
        raise _FieldError(f"{path}.hi", f"must exceed lo {list(lo)} on every axis", list(hi))
    if np.any(np.subtract(hi, lo) > MAX_WORLD_EXTENT):
        raise _FieldError(path, f"larger than {MAX_WORLD_EXTENT:g} m", f"lo={lo}, hi={hi}")
    _check_touches_bounds(lo, hi, bounds, path)
    return Box(name, lo, hi)


def _check_touches_bounds(lo: object, hi: object, bounds: Bounds, path: str) -> None:
    # An obstacle wholly outside the world is almost always a unit or sign error.
    if box_distance(lo, hi, bounds.lo, bounds.hi) > 0:
        raise _FieldError(
            path,
            f"lies entirely outside world.bounds {list(bounds.lo)}-{list(bounds.hi)}",
            f"lo={list(np.round(lo, 6))}, hi={list(np.round(hi, 6))}",
        )


def _mesh(data: object, path: str, folder: Path, bounds: Bounds) -> MeshObstacle:
    data = _as_mapping(data, path)
    inline = "vertices" in data or "faces" in data
    if inline:
        _check_keys(data, ("name", "vertices", "faces"), ("name", "vertices", "faces"), path)
    else:
        _check_keys(data, ("name", "file", "translate", "scale"), ("name", "file"), path)
    name = _as_name(data["name"], f"{path}.name")
    if inline:
        mesh = mesh_from_arrays(data["vertices"], data["faces"], name, what=path)
    else:
        file = resolve_inside(folder, _as_str(data["file"], f"{path}.file"), f"{path}.file")
        translate = _as_vec3(data.get("translate", [0, 0, 0]), f"{path}.translate")
        scale = _as_float(data.get("scale", 1.0), f"{path}.scale")
        if not 0 < scale <= 1000:  # beyond 1000x a mesh file is in the wrong unit
            raise _FieldError(f"{path}.scale", "must be in (0, 1000]", scale)
        mesh = load_mesh(file, name, translate=translate, scale=scale, what=f"{path}.file")
    if np.any(np.subtract(mesh.hi, mesh.lo) > MAX_WORLD_EXTENT):
        raise _FieldError(path, f"larger than {MAX_WORLD_EXTENT:g} m", f"{mesh.lo}-{mesh.hi}")
    _check_touches_bounds(mesh.lo, mesh.hi, bounds, path)
    return mesh


def _optional_path(value: object, folder: Path, path: str) -> Path | None:
    if value is None:
        return None
    return resolve_inside(folder, _as_str(value, path), path)


def _world(data: object, folder: Path) -> World:
    data = _as_mapping(data, "world")
    _check_keys(data, ("bounds", "boxes", "meshes", "octomap"), ("bounds",), "world")
    b = _as_mapping(data["bounds"], "world.bounds")
    _check_keys(b, ("lo", "hi"), ("lo", "hi"), "world.bounds")
    lo, hi = _as_vec3(b["lo"], "world.bounds.lo"), _as_vec3(b["hi"], "world.bounds.hi")
    bounds = Bounds(lo, hi)
    boxes = [
        _box(item, f"world.boxes[{i}]", bounds)
        for i, item in enumerate(_as_list(data.get("boxes"), "world.boxes"))
    ]
    meshes = [
        _mesh(item, f"world.meshes[{i}]", folder, bounds)
        for i, item in enumerate(_as_list(data.get("meshes"), "world.meshes"))
    ]
    seen: set[str] = set()
    for kind, items in (("boxes", boxes), ("meshes", meshes)):
        for i, o in enumerate(items):
            if o.name in seen:
                raise _FieldError(f"world.{kind}[{i}].name", "repeats an obstacle name", o.name)
            seen.add(o.name)
    if len(boxes) + len(meshes) > MAX_OBSTACLES:
        raise _FieldError("world", f"at most {MAX_OBSTACLES} obstacles", len(boxes) + len(meshes))
    octomap = _optional_path(data.get("octomap"), folder, "world.octomap")
    if octomap is not None:
        octomap_voxel_boxes(octomap, "world.octomap")  # parse now: a broken file fails at load
    return World(bounds, tuple(boxes), tuple(meshes), octomap)


_ATTACK_KEYS = {
    "hide": ("kind", "target"),
    "stale": ("kind", "target"),
    "shift": ("kind", "target", "offset"),
    "phantom": ("kind", "box"),
}


_REGION_KEYS = {"hide": ("kind", "region"), "phantom": ("kind", "region")}
_REGION_KEYS["shift"] = ("kind", "region", "by")


def _region_attack(data: dict[str, Any], path: str, world: World) -> Attack:
    kind = data["kind"]
    if kind not in _REGION_KEYS:
        raise _FieldError(f"{path}.kind", "a region attack is hide, shift or phantom", kind)
    _check_keys(data, _REGION_KEYS[kind], _REGION_KEYS[kind], path)
    region = _as_mapping(data["region"], f"{path}.region")
    _check_keys(region, ("lo", "hi"), ("lo", "hi"), f"{path}.region")
    lo = _as_vec3(region["lo"], f"{path}.region.lo")
    hi = _as_vec3(region["hi"], f"{path}.region.hi")
    if np.any(np.subtract(hi, lo) <= 0):
        raise _FieldError(f"{path}.region.hi", f"must exceed lo {list(lo)} on every axis", list(hi))
    _check_touches_bounds(lo, hi, world.bounds, f"{path}.region")
    by = _as_vec3(data["by"], f"{path}.by") if kind == "shift" else None
    return Attack(kind, offset=by, region=Region(lo, hi))


def _attack(data: object, path: str, world: World, taken: set[str]) -> Attack:
    data = _as_mapping(data, path)
    if "kind" not in data:
        kinds = ", ".join(ATTACK_KINDS)
        raise _FieldError(f"{path}.kind", f"missing required field (one of {kinds})")
    kind = data["kind"]
    if kind not in ATTACK_KINDS:
        raise _FieldError(f"{path}.kind", f"must be one of {', '.join(ATTACK_KINDS)}", kind)
    if "region" in data:
        return _region_attack(data, path, world)
    keys = _ATTACK_KEYS[kind]
    _check_keys(data, keys, keys, path)
    if kind == "phantom":
        box = _box(data["box"], f"{path}.box", world.bounds)
        if box.name in taken:
            raise _FieldError(f"{path}.box.name", "a phantom needs a name of its own", box.name)
        taken.add(box.name)
        return Attack("phantom", box=box)
    target = _as_name(data["target"], f"{path}.target")
    if target not in world.obstacle_names:
        known = ", ".join(world.obstacle_names) or "none"
        raise _FieldError(
            f"{path}.target", f"not an obstacle of the world (known: {known})", target
        )
    offset = _as_vec3(data["offset"], f"{path}.offset") if kind == "shift" else None
    return Attack(kind, target=target, offset=offset)


_SERVER_KEYS = ("resolution", "attacks", "octomap", "bt", "cloud", "origin", "mesh")


def _server_map(data: object, folder: Path, world: World) -> ServerMapSpec:
    data = _as_mapping(data if data is not None else {}, "server_map")
    _check_keys(data, _SERVER_KEYS, (), "server_map")
    sources = [k for k in ("octomap", "bt", "cloud", "mesh") if data.get(k) is not None]
    if len(sources) > 1:
        raise _FieldError("server_map", "give one of octomap, cloud, mesh", ", ".join(sources))
    taken = set(world.obstacle_names)
    attacks = [
        _attack(item, f"server_map.attacks[{i}]", world, taken)
        for i, item in enumerate(_as_list(data.get("attacks"), "server_map.attacks"))
    ]
    kwargs: dict[str, Any] = {"attacks": tuple(attacks)}
    if "resolution" in data:
        kwargs["resolution"] = _as_float(data["resolution"], "server_map.resolution")
    if sources:
        key = sources[0]
        file = _optional_path(data[key], folder, f"server_map.{key}")
        field = {"octomap": "bt"}.get(key, key)
        res = check_source_file(file, field, f"server_map.{key}")
        if res is not None and "resolution" in data and res != kwargs["resolution"]:
            raise _FieldError(
                "server_map.resolution",
                f"differs from the resolution {res:g} m of {file.name} (drop one or make them"
                " equal)",
                kwargs["resolution"],
            )
        kwargs[field] = file
    if "origin" in data:
        if not sources or sources[0] != "cloud":
            raise _FieldError("server_map.origin", "only a cloud has a sensor origin")
        kwargs["origin"] = _as_vec3(data["origin"], "server_map.origin")
    return ServerMapSpec(**kwargs)


def _check_vehicle_model(scenario: Scenario) -> None:
    """Build the dynamics model (as the planner will) so that its own checks judge the limits.

    Also checks that the model accepts the start state, that a differential drive does not start
    moving sideways or vertically, and that its start and goal lie at its fixed height.
    """
    from secure3d.dynamics import model_from_spec

    v, st = scenario.vehicle, scenario.start
    try:
        model = model_from_spec(v, scenario.camera)
    except ConfigError as exc:
        message = " ".join(str(exc).split())
        named = [k for k in v.limits if message.startswith(k) or f".{k}:" in message]
        field = f"vehicle.limits.{named[0]}" if named else "vehicle.limits"
        problem = message.split(": ", 1)[1] if named and ": " in message else message
        raise _FieldError(field, re.sub(r",? got (.*)$", r" (got \1)", problem)) from None
    try:
        model.initial_state(st.position, st.velocity, st.yaw)
    except ConfigError as exc:
        problem = " ".join(str(exc).split())
        raise _FieldError(
            "start.velocity",
            f"not a valid initial state for {v.model}: {problem}",
            list(st.velocity),
        ) from None
    if v.model == "diff_drive":
        heading = np.array([math.cos(st.yaw), math.sin(st.yaw), 0.0])
        lateral = np.subtract(st.velocity, np.dot(st.velocity, heading) * heading)
        if np.linalg.norm(lateral) > 1e-9 * (1.0 + np.linalg.norm(st.velocity)):
            raise _FieldError(
                "start.velocity",
                f"a diff_drive can only move along its heading yaw = {st.yaw:g} rad",
                list(st.velocity),
            )
    height = getattr(model.limits, "height", None)
    if v.model == "diff_drive" and height is not None:
        for what, p in (("start", st.position), ("goal", scenario.goal.position)):
            if abs(p[2] - height) > 1e-6:
                raise _FieldError(
                    f"{what}.position",
                    f"a diff_drive moves at its fixed height vehicle.limits.height = {height:g} m,"
                    " so z must equal it",
                    list(p),
                )


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------


def scenario_from_dict(
    data: object,
    folder: str | os.PathLike[str] = ".",
    *,
    source: str | os.PathLike[str] | None = None,
    label: str | None = None,
) -> Scenario:
    """Validate a parsed scenario (the YAML's top-level mapping) and build the :class:`Scenario`.

    Parameters
    ----------
    data : dict
        The scenario as plain Python data (as ``yaml.safe_load`` returns it).
    folder : path
        Folder that mesh and ``.bt`` paths are relative to; they must resolve inside it.
    source : path, optional
        Recorded as ``Scenario.source``.
    label : str, optional
        Name used at the start of error messages (default: ``source`` or ``"<scenario>"``).

    Returns
    -------
    Scenario

    Raises
    ------
    ScenarioError
        One line: ``"<label>: <field path>: <problem> (got <value>)"``.
    """
    label = label or (str(source) if source is not None else "<scenario>")
    folder = Path(folder)
    try:
        return _build(data, folder, Path(source) if source is not None else None)
    except _FieldError as exc:
        raise ScenarioError(f"{label}: {exc.line()}") from None
    except ScenarioError as exc:
        raise ScenarioError(f"{label}: {' '.join(str(exc).split())}") from None


def _build(data: object, folder: Path, source: Path | None) -> Scenario:
    if data is None:
        raise _FieldError("(top level)", "the scenario is empty")
    data = _as_mapping(data, "(top level)")
    _check_keys(data, _TOP_KEYS, _REQUIRED_TOP, "")
    name = _as_name(data["name"], "name")
    description = _as_str(data.get("description", ""), "description").strip()
    world = _world(data["world"], folder)
    scenario = Scenario(
        name=name,
        world=world,
        start=StartSpec(**_flat_section(StartSpec, data["start"], "start")),
        goal=GoalSpec(**_flat_section(GoalSpec, data["goal"], "goal")),
        server_map=_server_map(data.get("server_map"), folder, world),
        vehicle=VehicleSpec(**_flat_section(VehicleSpec, data.get("vehicle"), "vehicle")),
        camera=CameraSpec(**_flat_section(CameraSpec, data.get("camera"), "camera")),
        planner=PlannerSpec(**_flat_section(PlannerSpec, data.get("planner"), "planner")),
        simulation=SimulationSpec(
            **_flat_section(SimulationSpec, data.get("simulation"), "simulation")
        ),
        description=description,
        source=source,
    )
    _check_vehicle_model(scenario)
    octomap = scenario.world.octomap
    voxels = None if octomap is None else octomap_voxel_boxes(octomap, "world.octomap")
    check_start_goal_clear(scenario, voxels)
    return scenario


def load_scenario(path: str | os.PathLike[str]) -> Scenario:
    """Load and validate a scenario YAML file.

    Parameters
    ----------
    path : path or name
        The YAML file (schema in ``maps/README.md``), or the name of a shipped scenario
        (``"blind_corner"``; see :func:`secure3d.world.bundled.bundled_names`). Mesh and map
        paths inside it are relative to its folder.

    Returns
    -------
    Scenario
        Frozen and validated; ``print()`` it for a readable summary.

    Raises
    ------
    ScenarioError
        One line naming the file, the field and the bad value.
    """
    label = os.fspath(path)
    p = resolve_scenario(path)
    data = _read_yaml(p, label)
    return scenario_from_dict(data, p.resolve().parent, source=p.resolve(), label=label)


def _path_text(path: Path, folder: Path | None, what: str) -> str:
    if folder is not None and path.resolve().is_relative_to(folder.resolve()):
        return path.resolve().relative_to(folder.resolve()).as_posix()
    raise ScenarioError(f"{what}: {path} is not inside the destination folder {folder}")


def _plain(value: object) -> object:
    """Dataclass field value -> YAML/JSON-friendly value."""
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, np.generic):
        return value.item()
    return value


def _flat_dict(obj: object) -> dict[str, Any]:
    return {f.name: _plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}


def scenario_to_dict(
    scenario: Scenario, folder: str | os.PathLike[str] | None = None
) -> dict[str, Any]:
    """The scenario as plain data in the YAML schema, every default filled in.

    ``scenario_from_dict(scenario_to_dict(s, folder), folder)`` rebuilds an equivalent scenario.

    Parameters
    ----------
    scenario : Scenario
    folder : path, optional
        Folder that file references (meshes, ``.bt``) are written relative to; default: the folder
        of ``scenario.source``. Meshes built in Python (no file) are written inline as
        ``vertices``/``faces``.

    Raises
    ------
    ScenarioError
        If a referenced file is not inside ``folder`` (the loader would refuse it).
    """
    if folder is None and scenario.source is not None:
        folder = scenario.source.parent
    base = Path(folder) if folder is not None else None
    w, s = scenario.world, scenario.server_map

    def mesh_entry(i: int, m: MeshObstacle) -> dict[str, Any]:
        if m.path is None:
            return {"name": m.name, "vertices": m.vertices.tolist(), "faces": m.faces.tolist()}
        return {
            "name": m.name,
            "file": _path_text(m.path, base, f"world.meshes[{i}].file"),
            "translate": list(m.translate),
            "scale": m.scale,
        }

    def attack_entry(a: Attack) -> dict[str, Any]:
        if a.region is not None:
            entry = {"kind": a.kind, "region": _flat_dict(a.region)}
            if a.kind == "shift":
                entry["by"] = list(a.offset)
            return entry
        if a.kind == "phantom":
            return {"kind": "phantom", "box": _flat_dict(a.box)}
        entry: dict[str, Any] = {"kind": a.kind, "target": a.target}
        if a.kind == "shift":
            entry["offset"] = list(a.offset)
        return entry

    return {
        "name": scenario.name,
        "description": scenario.description,
        "world": {
            "bounds": _flat_dict(w.bounds),
            "boxes": [_flat_dict(b) for b in w.boxes],
            "meshes": [mesh_entry(i, m) for i, m in enumerate(w.meshes)],
            "octomap": None if w.octomap is None else _path_text(w.octomap, base, "world.octomap"),
        },
        "server_map": {
            "resolution": s.resolution,
            "attacks": [attack_entry(a) for a in s.attacks],
            **{
                key: _path_text(getattr(s, field), base, f"server_map.{key}")
                for key, field in (("octomap", "bt"), ("cloud", "cloud"), ("mesh", "mesh"))
                if getattr(s, field) is not None
            },
            **({"origin": list(s.origin)} if s.origin is not None else {}),
        },
        "vehicle": _flat_dict(scenario.vehicle),
        "camera": _flat_dict(scenario.camera),
        "start": _flat_dict(scenario.start),
        "goal": _flat_dict(scenario.goal),
        "planner": _flat_dict(scenario.planner),
        "simulation": _flat_dict(scenario.simulation),
    }


def save_scenario(scenario: Scenario, path: str | os.PathLike[str]) -> Path:
    """Write ``scenario`` as a YAML file that :func:`load_scenario` reads back.

    File references are written relative to the new file's folder, so every mesh and ``.bt`` must
    lie inside it (``ScenarioError`` otherwise).

    Returns
    -------
    Path
        The written file.
    """
    path = Path(path)
    data = scenario_to_dict(scenario, path.resolve().parent)
    text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
    path.write_text(text, encoding="utf-8")
    return path
