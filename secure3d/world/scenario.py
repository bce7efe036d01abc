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

import math
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from secure3d.errors import ConfigError, ScenarioError
from secure3d.world.attacks import octomap_voxel_boxes
from secure3d.world.bundled import resolve_scenario
from secure3d.world.meshes import load_mesh, mesh_from_arrays, resolve_inside
from secure3d.world.placement import check_start_goal_clear
from secure3d.world.scenario_fields import (  # noqa: F401  (MAX_*: re-exported)
    MAX_EXPANDED_VALUES,
    MAX_SCENARIO_BYTES,
    _as_float,
    _as_list,
    _as_mapping,
    _as_name,
    _as_str,
    _as_vec3,
    _check_keys,
    _FieldError,
    _flat_section,
    _read_yaml,
)
from secure3d.world.scenario_writer import save_scenario, scenario_to_dict
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


_SERVER_KEYS = ("resolution", "attacks", "octomap", "bt", "cloud", "origin", "mesh", "lacks")


def _server_map(data: object, folder: Path, world: World) -> ServerMapSpec:
    data = _as_mapping(data if data is not None else {}, "server_map")
    if "survey" in data:  # what scenario_to_dict notes for a survey held in memory
        raise _FieldError(
            "server_map.survey",
            "a survey held in memory; save_scenario writes it as a .graph"
            " file, named by server_map.cloud",
            data["survey"],
        )
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
    if "lacks" in data:
        names = _as_list(data["lacks"], "server_map.lacks")
        for i, name in enumerate(names):
            if not isinstance(name, str) or name not in taken:
                raise _FieldError(
                    f"server_map.lacks[{i}]",
                    f"not an obstacle of the world (known: {', '.join(sorted(taken)) or 'none'})",
                    name,
                )
        if not sources:
            raise _FieldError(
                "server_map.lacks",
                "only a server map given as a file lacks obstacles; use a hide attack",
                names,
            )
        kwargs["lacks"] = tuple(names)
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
    if model.heading_follows_path:
        heading = np.array([math.cos(st.yaw), math.sin(st.yaw), 0.0])
        lateral = np.subtract(st.velocity, np.dot(st.velocity, heading) * heading)
        if np.linalg.norm(lateral) > 1e-9 * (1.0 + np.linalg.norm(st.velocity)):
            raise _FieldError(
                "start.velocity",
                f"a {v.model} can only move along its heading yaw = {st.yaw:g} rad",
                list(st.velocity),
            )
    height = getattr(model.limits, "height", None)
    if model.planar and height is not None:
        for what, p in (("start", st.position), ("goal", scenario.goal.position)):
            if abs(p[2] - height) > 1e-6:
                raise _FieldError(
                    f"{what}.position",
                    f"a {v.model} moves at its fixed height vehicle.limits.height = {height:g} m,"
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
