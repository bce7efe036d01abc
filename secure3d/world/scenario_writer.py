"""Scenarios back to plain data and YAML files (:func:`scenario_to_dict`, :func:`save_scenario`):
what :func:`secure3d.world.scenario.load_scenario` reads gives the same scenario back. Re-exported
by :mod:`secure3d.world.scenario`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from secure3d.errors import ScenarioError
from secure3d.world.spec import (
    Attack,
    MeshObstacle,
    Scenario,
)


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
            **({"survey": _survey_note(s.survey)} if s.survey is not None else {}),
            **({"lacks": list(s.lacks)} if s.lacks else {}),
        },
        "vehicle": _flat_dict(scenario.vehicle),
        "camera": _flat_dict(scenario.camera),
        "start": _flat_dict(scenario.start),
        "goal": _flat_dict(scenario.goal),
        "planner": _flat_dict(scenario.planner),
        "simulation": _flat_dict(scenario.simulation),
    }


def _survey_note(survey: bytes) -> str:
    digest = hashlib.sha256(survey).hexdigest()[:16]
    return f"scan graph in memory, {len(survey)} bytes, sha256 {digest}"


def with_survey_file(scenario: Scenario, path: str | os.PathLike[str]) -> Scenario:
    """``scenario`` with its in-memory survey (``server_map.survey``) written to ``path`` (a
    ``.graph`` file) and named as ``server_map.cloud``; unchanged without one."""
    s = scenario.server_map
    if s.survey is None:
        return scenario
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(s.survey)
    server = dataclasses.replace(s, survey=None, cloud=path.resolve())
    return dataclasses.replace(scenario, server_map=server)


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
    scenario = with_survey_file(scenario, path.with_suffix(".graph"))
    data = scenario_to_dict(scenario, path.resolve().parent)
    text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=100)
    path.write_text(text, encoding="utf-8")
    return path
