"""The ``survey`` campaign family: the server's map is a lidar survey made before the world changed.

The scene class of ``maps/warehouse_survey.yaml``, over any base. Variant ``i``:

- a hidden obstacle across the route, placed by the ``auto`` rule
  (:func:`~secure3d.world.hidden_obstacles.hidden_obstacle_family`);
- the survey sees the world as the base's server knows it (its hidden obstacles absent, its
  shifted ones moved, its phantoms there) or, for a server map file, every true obstacle;
- with probability :data:`MOVED_PROBABILITY`, one named obstacle near the route stood elsewhere
  when the survey was made (0.3-1.0 m away horizontally), as in a stale map;
- the server's map becomes an OctoMap scan graph (``server_map.survey``, held in memory) of 2-4
  scans of a rotating lidar (360 degrees in azimuth every :data:`AZIMUTH_STEP_DEG`, a vertical
  field of +-15 to +-30 degrees every :data:`ELEVATION_STEP_DEG`, :data:`LIDAR_RANGE` m) from the
  start, the goal and points between them clear of every surveyed obstacle, each pose yawed at
  random and tilted by up to 8 degrees (roll up to 3). The survey is cast against the world as it
  was: without the hidden obstacle, with the moved one where it stood.

So the server claims free whatever its rays crossed (the hidden obstacle's place among it), claims
the moved obstacle where it is not, leaves unknown what the lidar did not see, and claims surfaces
as the sparse stripes a multi-ring lidar leaves. The base's named attacks are dropped (a survey
reports what the lidar saw); its region attacks are kept. Variant ``i`` is a pure function of
(base, seed, i).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.world.families import Family
from secure3d.world.spec import Box, MeshObstacle, Scenario

__all__ = ["SURVEY", "survey_family", "survey_scans"]

#: Probability that one named obstacle near the route was elsewhere when surveyed.
MOVED_PROBABILITY = 0.5
#: A named obstacle is a candidate to have moved when it lies this close to the route (m) and is
#: no wider than this fraction of the world along x and y (floors, ceilings and long walls stay).
MOVED_NEAR_ROUTE, MOVED_MAX_SPAN = 2.0, 0.6
#: Lidar: azimuth and elevation steps (degrees) and range (m).
AZIMUTH_STEP_DEG, ELEVATION_STEP_DEG, LIDAR_RANGE = 0.8, 2.0, 20.0
#: A survey pose keeps this far (m) from every surveyed obstacle.
POSE_CLEARANCE = 0.3


@dataclass(frozen=True, eq=False)
class _Prepared:
    hidden: Any  # the auto placement's prepared state
    named: tuple[Box | MeshObstacle, ...]  # the named obstacles the survey sees
    voxel_boxes: np.ndarray  # (n, 2, 3) of world.octomap
    voxel_mesh: tuple[np.ndarray, np.ndarray]  # their triangles, built once


def _prepare(base: Scenario, place: Callable[[Scenario], Any]) -> _Prepared:
    """The survey sees the world as the base's server knows it: for a server map derived from
    the world, its claim (hidden and stale obstacles absent, shifted ones moved, phantoms there);
    else every true named obstacle. ``world.octomap``'s voxels always. ``place``: the hidden
    obstacle placement's ``prepare`` (see :func:`survey_family`)."""
    from secure3d.geometry.box_mesh import box_arrays
    from secure3d.world.attacks import server_claim
    from secure3d.world.truth import true_obstacles

    truth = true_obstacles(base)
    known = server_claim(base) if base.server_map.from_world else truth
    hidden = place(base)
    vb = truth.voxel_boxes
    return _Prepared(hidden, (*known.boxes, *known.meshes), vb, box_arrays(vb[:, 0], vb[:, 1]))


def _rotation(rng: np.random.Generator) -> np.ndarray:
    """(w, x, y, z) of ``Rz(yaw) Ry(pitch) Rx(roll)``: any yaw, pitch up to 8, roll up to 3 deg."""
    from secure3d.mapping.scan_graph import euler_quaternion

    pitch, roll = np.radians(rng.uniform(-8.0, 8.0)), np.radians(rng.uniform(-3.0, 3.0))
    return euler_quaternion(roll, pitch, rng.uniform(-np.pi, np.pi))


def _triangles(named: tuple, voxel_mesh: tuple) -> tuple[np.ndarray, np.ndarray]:
    """One triangle soup (vertices (v, 3), faces (f, 3)) of named obstacles and voxel boxes."""
    from secure3d.geometry.box_mesh import box_arrays

    boxes = [o for o in named if isinstance(o, Box)]
    parts = [box_arrays([b.lo for b in boxes], [b.hi for b in boxes]), voxel_mesh]
    parts += [
        (np.asarray(m.vertices), np.asarray(m.faces)) for m in named if isinstance(m, MeshObstacle)
    ]
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    vertices = np.concatenate([v for v, _ in parts])
    faces = np.concatenate([f + off for (_, f), off in zip(parts, offsets, strict=True)])
    return vertices, faces


def survey_scans(
    vertices: np.ndarray,
    faces: np.ndarray,
    poses: list[tuple[np.ndarray, np.ndarray]],
    half_elevation_deg: float,
    azimuth_step_deg: float = AZIMUTH_STEP_DEG,
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Cast a rotating lidar at every pose against the triangles.

    Parameters
    ----------
    vertices : (v, 3) float ; faces : (f, 3) int
    poses : list of (translation (3,), quaternion (4,) as w, x, y, z)
    half_elevation_deg : the vertical field is +-this (degrees), in rings
        :data:`ELEVATION_STEP_DEG` apart
    azimuth_step_deg : degrees between two rays of a ring

    Returns
    -------
    list of (points (n, 3) in the sensor frame, translation (3,), quaternion (4,)): the hits within
    :data:`LIDAR_RANGE`, ready for :func:`~secure3d.mapping.scan_graph.write_scan_graph_bytes`.
    """
    from secure3d._deps import open3d
    from secure3d.errors import GeometryError
    from secure3d.mapping.scan_graph import rotation_matrix

    vertices, faces = np.asarray(vertices, dtype=float), np.asarray(faces)
    if (
        vertices.ndim != 2
        or vertices.shape[1:] != (3,)
        or faces.ndim != 2
        or faces.shape[1:] != (3,)
    ):
        raise GeometryError(
            f"survey_scans: vertices and faces must be (n, 3), got {vertices.shape}, {faces.shape}"
        )
    if not 0.0 < half_elevation_deg <= 90.0:
        raise GeometryError(
            f"survey_scans: half_elevation_deg must be in (0, 90], got {half_elevation_deg!r}"
        )
    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.asarray(vertices, np.float32)),
        o3d.core.Tensor(np.asarray(faces, np.uint32)),
    )
    if not 0.0 < azimuth_step_deg <= 90.0:
        raise GeometryError(
            f"survey_scans: azimuth_step_deg must be in (0, 90], got {azimuth_step_deg!r}"
        )
    az = np.radians(np.arange(-180.0, 180.0, azimuth_step_deg))
    el = np.radians(np.arange(-half_elevation_deg, half_elevation_deg + 1e-9, ELEVATION_STEP_DEG))
    a, e = np.meshgrid(az, el, indexing="ij")
    local = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    scans = []
    for t, q in poses:
        d = local @ rotation_matrix(q).T
        rays = np.concatenate([np.broadcast_to(t, d.shape), d], axis=1).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        ok = np.isfinite(hit) & (hit <= LIDAR_RANGE)
        scans.append((local[ok] * hit[ok, None], np.asarray(t, float), np.asarray(q, float)))
    return scans


def _moved(prep: _Prepared, base: Scenario, rng: np.random.Generator) -> tuple:
    """The surveyed named obstacles, one of them maybe where it stood before; and a note."""
    a, b = np.asarray(base.start.position), np.asarray(base.goal.position)
    span = np.subtract(base.world.bounds.hi, base.world.bounds.lo)
    along = np.linspace(a, b, 50)
    near = []
    for k, o in enumerate(prep.named):
        lo, hi = np.asarray(o.lo), np.asarray(o.hi)
        if np.any((hi - lo)[:2] > MOVED_MAX_SPAN * span[:2]):
            continue
        gap = np.maximum(np.maximum(lo - along, along - hi), 0.0)
        if np.linalg.norm(gap, axis=1).min() <= MOVED_NEAR_ROUTE:
            near.append(k)
    if not near or rng.uniform() >= MOVED_PROBABILITY:
        return prep.named, ""
    k = near[int(rng.integers(len(near)))]
    angle = rng.uniform(0.0, 2.0 * np.pi)
    by = rng.uniform(0.3, 1.0) * np.array([np.cos(angle), np.sin(angle), 0.0])
    named = list(prep.named)
    named[k] = named[k].shifted(tuple(float(x) for x in by))
    return tuple(named), f" {prep.named[k].name} stood {np.round(by, 2).tolist()} m away then."


def _shifted_names(before: tuple, after: tuple, real: tuple[str, ...]) -> tuple[str, ...]:
    """Names among ``real`` (the world's obstacles) of those :func:`_moved` surveyed elsewhere than
    they stand (a phantom of the base's server, surveyed elsewhere, stands nowhere: nothing to
    leave out)."""
    return tuple(
        a.name for a, b in zip(before, after, strict=True) if a is not b and a.name in real
    )


def _poses(prep: _Prepared, named: tuple, base: Scenario, rng: np.random.Generator) -> list:
    a, b = np.asarray(base.start.position), np.asarray(base.goal.position)
    lo = np.array([o.lo for o in named] + [v[0] for v in prep.voxel_boxes]).reshape(-1, 3)
    hi = np.array([o.hi for o in named] + [v[1] for v in prep.voxel_boxes]).reshape(-1, 3)
    points = [a, b] + [a + f * (b - a) for f in rng.uniform(0.2, 0.8, int(rng.integers(0, 3)))]
    poses = []
    for p in points:
        gap = np.maximum(np.maximum(lo - p, p - hi), 0.0)
        if not len(lo) or np.linalg.norm(gap, axis=1).min() >= POSE_CLEARANCE:
            poses.append((np.asarray(p, np.float32).astype(float), _rotation(rng)))
    return poses


def _variant(prep: _Prepared, base: Scenario, rng: np.random.Generator, i: int) -> Scenario:
    from secure3d.mapping.scan_graph import write_scan_graph_bytes
    from secure3d.world.spec import ServerMapSpec

    v = prep.hidden.variant(base, rng, i, 1)
    named, moved = _moved(prep, base, rng)
    poses = _poses(prep, named, base, rng)
    half_elevation = float(rng.uniform(15.0, 30.0))
    scans = survey_scans(*_triangles(named, prep.voxel_mesh), poses, half_elevation)
    if not sum(len(s[0]) for s in scans):
        raise ScenarioError(f"{base.name}: the survey of variant {i} hit nothing")
    regions = tuple(a for a in base.server_map.attacks if a.region is not None)
    server = ServerMapSpec(
        attacks=regions,
        resolution=base.server_map.resolution,
        survey=write_scan_graph_bytes(scans),
        # what the base's server hid, the new obstacle, and one surveyed where it stood before
        # (as a stale attack's target, hidden where it stands now)
        lacks=tuple(
            dict.fromkeys(
                (*v.hidden_obstacles, *_shifted_names(prep.named, named, v.world.obstacle_names))
            )
        ),
    )
    hidden = ", ".join(b.name for b in v.world.boxes[len(base.world.boxes) :])
    note = (
        f"Variant {i} of survey: the server's map is a lidar survey ({len(scans)} scans) made"
        f" before {hidden} was put there.{moved}"
    )
    return dataclasses.replace(
        v,
        name=f"{base.name}_survey_{i:03d}",
        server_map=server,
        description=f"{base.description} {note}".strip(),
    )


def survey_family(footprint: float | None = None) -> Family:
    """The survey family. ``footprint`` (m, optional): the half-width of the narrowest corridor the
    planners flown can use at a standstill, as for the ``auto`` placement
    (:func:`~secure3d.world.hidden_obstacles.hidden_obstacle_family`): a gap beside the hidden
    obstacle then holds twice it after losing a map voxel on each side. Campaigns pass the secure
    planner's (:func:`~secure3d.simulation.campaign_run.campaign_family`); without it the gaps
    follow the body radius alone, and for a quadrotor, whose reactive set at rest reaches 0.3 m
    a side, they came out 0.73 m wide: passable only at a crawl, if at all. A footprint that is not
    a number of metres in (0, 5) raises :class:`ScenarioError` naming it."""
    from secure3d.world.hidden_obstacles import hidden_obstacle_family

    placement = hidden_obstacle_family("auto", 1, footprint)  # checks the footprint
    return Family(
        name="survey",
        description=(
            "the server's map is a lidar survey (an OctoMap scan graph of 2-4 posed scans) made"
            " before a hidden obstacle was put across the route and, half the time, before a named"
            " obstacle near it moved"
        ),
        prepare=functools.partial(_prepare, place=placement.prepare),
        variant=_variant,
    )


SURVEY = survey_family()
