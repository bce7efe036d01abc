"""Figures of closed-loop runs: one run's top view (``simulate(png=...)``) and several runs of
one scenario side by side (top view and speed profiles). They only read finished
:class:`~secure3d.simulation.results.SimResult` s and the scenario.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.simulation.results import SimResult
    from secure3d.world.spec import Scenario

__all__ = ["comparison_figures", "plans_figure", "run_figure", "scenario_layers", "scenario_voxels"]


def scenario_layers(scenario: Scenario) -> dict:
    """Keyword arguments of :func:`~secure3d.viz.figures.top_down_figure` drawing what every
    figure of ``scenario`` shows: the true world (hidden obstacles marked), the server's claim, the
    start and the goal."""
    from secure3d.world.attacks import server_claim

    claim = server_claim(scenario)
    return {
        "bounds": scenario.world.bounds,
        "true_boxes": scenario.world.boxes,
        "true_meshes": scenario.world.meshes,
        "claimed_boxes": claim.boxes,
        "claimed_meshes": claim.meshes,
        "hidden_names": scenario.hidden_obstacles,
        "start": np.asarray(scenario.start.position),
        "goal": np.asarray(scenario.goal.position),
    }


def plans_figure(scenario: Scenario, plans: Sequence[Any], png: str | os.PathLike[str]) -> Path:
    """Open-loop plans (``secure3d plan --png``) over ``scenario``'s world and claim."""
    from secure3d.viz.figures import top_down_figure

    return top_down_figure(
        out_path=png,
        plans=[p for p in plans if len(p.positions)],
        title=f"{scenario.name}: plans in the server's map",
        **scenario_layers(scenario),
    )


def scenario_voxels(scenario: Scenario) -> dict:
    """Keyword arguments of :func:`~secure3d.viz.figures.top_down_figure` drawing
    ``world.octomap``'s voxels (in a colour tree's colours) and the server map's claimed voxels
    when it is a file or is attacked by region."""
    from secure3d.world.attacks import (
        belief_map,
        octomap_voxel_colors,
        server_claim,
        true_obstacles,
    )

    claim = server_claim(scenario)
    file_claim = not scenario.server_map.from_world
    claimed = belief_map(scenario).claimed_voxels(True) if file_claim or claim.regions else None
    octomap = scenario.world.octomap
    colors = None if octomap is None else octomap_voxel_colors(octomap, "world.octomap")
    return {
        "voxel_boxes": true_obstacles(scenario).voxel_boxes,
        "voxel_colors": colors,
        "claimed_voxels": claimed,
        "voxel_size": scenario.server_map.resolution,
    }


def run_figure(scenario: Scenario, result: SimResult, png: str | os.PathLike[str]) -> Path:
    """The top view of one run (its first plan, flown path, detection and collision points),
    written atomically to ``png``."""
    from secure3d.viz.figures import top_down_figure

    return top_down_figure(
        scenario.world.bounds,
        scenario.world.boxes,
        true_meshes=scenario.world.meshes,
        out_path=png,
        hidden_names=scenario.hidden_obstacles,
        plans=[p for _, p in result.plans[:1]],
        realised_paths={result.planner: result.positions},
        detection_points=[result.detection_point] if result.detection_point is not None else None,
        start=np.asarray(scenario.start.position),
        goal=np.asarray(scenario.goal.position),
        collision_points=[result.positions[-1]] if result.collided else (),
        title=f"{scenario.name}: {result.planner} ({result.outcome})",
        **scenario_voxels(scenario),
    )


#: Events marked on the speed profiles, with their short labels.
_MARKED_EVENTS = {
    "hidden obstacle seen": "seen",
    "take-over": "take-over",
    "collision": "collision",
}
#: Events closer than this (s) share one marker, so their labels do not print over each other.
_MARKER_MERGE = 0.25


def _speed_markers(result: SimResult) -> list[tuple[float, str]]:
    markers: list[tuple[float, str]] = []
    for event in result.events:
        label = _MARKED_EVENTS.get(event.kind)
        if label is None:
            continue
        if markers and event.time - markers[-1][0] < _MARKER_MERGE:
            markers[-1] = (markers[-1][0], f"{markers[-1][1]}, {label}")
        else:
            markers.append((event.time, label))
    return markers


def comparison_figures(
    scenario: Scenario,
    results: Sequence[SimResult],
    top_down: str | os.PathLike[str] | None = None,
    speed: str | os.PathLike[str] | None = None,
) -> dict[str, Path]:
    """Figures of several runs of one scenario (atomic PNGs, folders created if missing).

    Parameters
    ----------
    scenario : the scenario flown.
    results : its runs (one per planner).
    top_down : paper-style top view: realised paths solid, each run's first plan dashed with its
        reactive sets (eq. ReactEllipse), detection points as red X, collisions as stars.
    speed : speed over time of each run, with the first sighting of a hidden obstacle, take-overs
        and collisions marked.

    Returns
    -------
    dict
        ``{"top_down": path, "speed": path}`` for the figures written.
    """
    from secure3d.dynamics import model_from_spec
    from secure3d.viz.figures import top_down_figure
    from secure3d.viz.speed_figure import speed_profile_figure

    written: dict[str, Path] = {}
    if top_down is not None:
        Path(top_down).parent.mkdir(parents=True, exist_ok=True)
        written["top_down"] = top_down_figure(
            out_path=top_down,
            plans=[r.plans[0][1] for r in results if r.plans],
            realised_paths={r.planner: r.positions for r in results},
            detection_points={
                r.planner: r.detection_point for r in results if r.detection_point is not None
            },
            collision_points=[r.positions[-1] for r in results if r.collided],
            title=f"{scenario.name}: " + ", ".join(f"{r.planner} {r.outcome}" for r in results),
            **scenario_layers(scenario),
        )
    if speed is not None:
        Path(speed).parent.mkdir(parents=True, exist_ok=True)
        written["speed"] = speed_profile_figure(
            {r.planner: (r.times, r.speeds) for r in results},
            speed,
            markers={r.planner: _speed_markers(r) for r in results},
            speed_limit=float(model_from_spec(scenario.vehicle, scenario.camera).limits.max_speed),
            title=f"{scenario.name}: speed",
        )
    return written
