"""The server's (possibly tampered) map, the true obstacles, random hidden-obstacle variants.

The paper's threat model (DESIGN.md section 1): the map server may delete obstacles (``hide``: the
dangerous case; ``stale``: the map predates the obstacle), invent them (``phantom``) or move them
(``shift``). This module turns a :class:`~secure3d.world.spec.Scenario` into

- :func:`server_claim`: what the server reports (the truth with the attacks applied, or its own
  ``.bt``);
- :func:`belief_map`: the robot's initial :class:`~secure3d.mapping.occupancy.OccupancyMap`, whose
  claim layer holds that report and which has no sensor evidence yet;
- :func:`true_obstacles`: what the simulator collides with and ray-casts;
- :func:`random_hidden_obstacle_scenarios`: variants of a scenario with extra true obstacles the
  server hides, placed where they matter (for collision-rate campaigns).
"""

from __future__ import annotations

import hashlib
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from secure3d._bounded_cache import BoundedCache
from secure3d.world.hidden_obstacles import (  # noqa: F401  (re-exported)
    GAP_ALLOWANCE,
    PLACEMENT_CLEARANCE,
    hidden_obstacle_family,
    random_hidden_obstacle_scenarios,
)
from secure3d.world.octomap_files import (  # noqa: F401  (re-exported: the public names)
    MAX_BT_BYTES,
    OCTOMAP_SUFFIXES,
    octomap_leaves,
    octomap_resolution,
    octomap_voxel_boxes,
    octomap_voxel_colors,
)
from secure3d.world.spec import Attack, Box, MeshObstacle, Scenario
from secure3d.world.truth import TrueObstacles, true_obstacles

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.mapping.occupancy import OccupancyMap

__all__ = [
    "ServerClaim",
    "TrueObstacles",
    "belief_map",
    "hidden_obstacle_family",
    "random_hidden_obstacle_scenarios",
    "server_claim",
    "true_obstacles",
]


@dataclass(frozen=True)
class ServerClaim:
    """What the map server reports.

    Attributes
    ----------
    boxes : tuple of Box
        Claimed box obstacles (true ones minus hidden, shifted ones moved, phantoms added).
    meshes : tuple of MeshObstacle
        Claimed mesh obstacles.
    bt : Path or None
        An OctoMap (``.bt``/``.ot``) whose occupied voxels are claimed obstacles: the server map's
        own file (then ``boxes`` and ``meshes`` are empty), else the true world's
        ``world.octomap`` (reported as is but for region attacks).
    cloud, mesh : Path or None
        The server map as a point cloud (rays from ``origin``, or bare points without it) or as a
        mesh surface (see :mod:`secure3d.world.server_sources`).
    survey : bytes or None
        The server map as an OctoMap scan graph held in memory (each scan from its pose).
    regions : tuple of Attack
        Region attacks, applied voxel by voxel after everything above is claimed.
    """

    boxes: tuple[Box, ...] = ()
    meshes: tuple[MeshObstacle, ...] = ()
    bt: Path | None = None
    cloud: Path | None = None
    origin: tuple[float, float, float] | None = None
    mesh: Path | None = None
    survey: bytes | None = None
    regions: tuple[Attack, ...] = ()


def server_claim(scenario: Scenario) -> ServerClaim:
    """The server's report: the true named obstacles with the attacks applied, or its ``.bt``.

    Attacks apply in file order: ``hide``/``stale`` remove the target, ``shift`` moves it by its
    offset, ``phantom`` adds its box. Obstacles keep the world's order; phantoms come last.
    """
    spec = scenario.server_map
    regions = tuple(a for a in spec.attacks if a.region is not None)
    if not spec.from_world:
        return ServerClaim(
            bt=spec.bt,
            cloud=spec.cloud,
            origin=spec.origin,
            mesh=spec.mesh,
            survey=spec.survey,
            regions=regions,
        )
    world = scenario.world
    claimed: dict[str, Box | MeshObstacle] = {o.name: o for o in (*world.boxes, *world.meshes)}
    for attack in spec.attacks:
        if attack.region is not None:
            continue
        if attack.kind in ("hide", "stale"):
            del claimed[attack.target]
        elif attack.kind == "shift":
            claimed[attack.target] = claimed[attack.target].shifted(attack.offset)
        else:
            claimed[attack.box.name] = attack.box
    return ServerClaim(
        boxes=tuple(o for o in claimed.values() if isinstance(o, Box)),
        meshes=tuple(o for o in claimed.values() if isinstance(o, MeshObstacle)),
        bt=world.octomap,
        regions=regions,
    )


def belief_map(scenario: Scenario, resolution: float | None = None) -> OccupancyMap:
    """The robot's initial map: the server's claim in the claim layer, no sensor evidence.

    Claimed boxes and meshes become claimed-occupied voxels (every voxel they touch); space between
    them stays unclaimed, since a server listing obstacles says nothing voxel by voxel. A claimed
    ``.bt`` contributes its occupied and free leaves; at another resolution than the map's only
    its occupied leaves are claimed, each on every voxel it touches (conservative; for the planner
    unclaimed and claimed-free space are alike).

    Parameters
    ----------
    scenario : Scenario
    resolution : float, optional
        Voxel size (m); default ``scenario.server_map.resolution``.

    Returns
    -------
    OccupancyMap
        Spanning the world bounds. Known obstacles = claimed occupied voxels until the camera says
        otherwise (DESIGN.md section 4, map update rules). The caller's own copy: each claim is
        built once per resolution, bounds and content of the files it names, then copied from
        a small cache.
    """
    res = scenario.server_map.resolution if resolution is None else resolution
    b = scenario.world.bounds
    claim = server_claim(scenario)
    key = _belief_key(claim, res, b.lo, b.hi)
    cached = None if key is None else _BELIEFS.get(key)
    if cached is None:
        cached = _claimed_belief(claim, res, (b.lo, b.hi))
        if key is not None:
            _BELIEFS.put(key, cached)
    # The cached map is never handed out: every caller gets its own copy (1-2 ms on a real scan,
    # against 60-80 ms to read and claim its file). Copies share its merged boxes until changed.
    return cached.copy()


# Beliefs by what they are built from: the claim (boxes, meshes, attacks, paths), the content of
# the files it names, the resolution and the bounds. A plan() call, a campaign's variants and the
# closed loop's reset over one server map then read and claim its file once.
BELIEF_CACHE_SIZE = 4
#: Claimed voxels the cached beliefs may hold in all (about 11 bytes each with their merged boxes:
#: the geb079 scan claims 1.14 M, 12.6 MB). A larger belief is built afresh every time.
MAX_CACHED_CLAIMS = 1 << 24
MAX_DIGESTED_BYTES = 1 << 28  # larger files are read afresh every time (no digest)


def _claims(belief: object) -> int:
    """What a cached belief holds, for the cache's budget: its claimed voxels."""
    return belief.claimed_count  # type: ignore[attr-defined]


_BELIEFS = BoundedCache(BELIEF_CACHE_SIZE, MAX_CACHED_CLAIMS, _claims)


def _file_digest(path: Path) -> tuple[str, int, str]:
    """What identifies a file's content: its real path, size and BLAKE2b digest (0.3 ms for the
    geb079 scan, against 60-80 ms to read and claim it). Timestamps alone could miss a rewrite
    within their granularity. Raises OSError for what is not a regular file of at most
    :data:`MAX_DIGESTED_BYTES`."""
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_DIGESTED_BYTES:
        raise OSError(f"{path}: not digested")
    with open(path, "rb") as f:
        data = f.read(MAX_DIGESTED_BYTES + 1)
    return os.path.realpath(path), len(data), hashlib.blake2b(data, digest_size=20).hexdigest()


def _belief_key(claim: ServerClaim, res: float, lo: object, hi: object) -> tuple | None:
    """The belief cache's key, or None (not cached) when a named file cannot be digested (the
    build then raises its own error) or a part of the claim cannot be hashed."""
    try:
        files = (claim.bt, claim.cloud, claim.mesh)
        digests = tuple(None if p is None else _file_digest(p) for p in files)
        key = (claim, digests, float(res), tuple(lo), tuple(hi))  # type: ignore[arg-type]
        hash(key)
    except (OSError, TypeError):
        return None
    return key


def _claimed_belief(claim: ServerClaim, res: float, bounds: tuple[object, object]) -> OccupancyMap:
    """A fresh map spanning ``bounds`` whose claim layer holds ``claim`` (see :func:`belief_map`)."""
    from secure3d.mapping.occupancy import OccupancyMap

    belief = OccupancyMap(res, bounds=bounds)  # type: ignore[arg-type]
    if claim.boxes:
        lo = np.array([o.lo for o in claim.boxes])
        hi = np.array([o.hi for o in claim.boxes])
        belief.set_claim_boxes(lo, hi, occupied=True)
    for mesh in claim.meshes:
        belief.set_claim_mesh(mesh.vertices, mesh.faces)
    if claim.bt is not None:
        server = OccupancyMap.read_bt(claim.bt)
        if server.resolution == res:
            belief.set_claim_from_map(server)
        else:
            centres, sizes, log_odds = server.leaves()
            occupied = log_odds >= server.params.threshold_log
            half = 0.5 * sizes[occupied, None]
            belief.set_claim_boxes(centres[occupied] - half, centres[occupied] + half)
    _claim_sources(belief, claim, res)
    for attack in claim.regions:
        apply_region_attack(belief, attack)
    return belief


def _claim_sources(belief: OccupancyMap, claim: ServerClaim, res: float) -> None:
    """Claim a point-cloud, scan-graph or mesh server map (:mod:`secure3d.world.server_sources`)."""
    from secure3d.mapping.occupancy import OccupancyMap
    from secure3d.world import server_sources

    if claim.cloud is not None or claim.survey is not None:
        what = "server_map.cloud"
        if claim.survey is not None:
            scans = server_sources.read_survey_scans(claim.survey)
        else:
            scans = server_sources.read_cloud_scans(claim.cloud, what)
        server = OccupancyMap(res)
        if server_sources.insert_cloud(server, scans, claim.origin):
            belief.set_claim_from_map(server)
        else:
            belief.set_claim_voxels(scans.points, True)
    if claim.mesh is not None:
        v, f = server_sources.read_surface_mesh(claim.mesh, "server_map.mesh")
        belief.set_claim_voxels(server_sources.surface_voxel_centres(v, f, res), True)


def apply_region_attack(belief: OccupancyMap, attack: Attack) -> None:
    """Tamper with the claim layer of ``belief`` in ``attack.region`` (see
    :class:`~secure3d.world.spec.Attack`).

    ``hide``: every claimed voxel whose centre lies in the region is claimed free. ``shift``: the
    region's claimed-occupied voxels are claimed free and re-claimed occupied ``offset`` away
    (rounded to whole voxels). ``phantom``: every voxel the region touches is claimed occupied.
    The sensor layer is untouched: the robot's own evidence still overrides every claim.
    """
    lo, hi = np.asarray(attack.region.lo), np.asarray(attack.region.hi)
    if attack.kind == "phantom":
        belief.set_claim_boxes(lo[None], hi[None], occupied=True)
        return
    occ = belief.claimed_voxels(True)
    inside = occ[np.all((occ >= lo) & (occ <= hi), axis=1)]
    if attack.kind == "hide":
        # Also free what the region claimed free already: nothing else changes.
        if len(inside):
            belief.set_claim_voxels(inside, False)
        return
    if not len(inside):
        return
    res = belief.resolution
    step = np.round(np.asarray(attack.offset, float) / res) * res
    belief.set_claim_voxels(inside, False)
    belief.set_claim_voxels(inside + step, True)
