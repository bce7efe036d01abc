"""Random region attacks on any server map: a campaign family over a user's own scan.

Each variant adds one region attack (:class:`~secure3d.world.spec.Attack` with a ``region``) to
the base scenario's server map, which may be an OctoMap file, a point cloud, a mesh or the world's
named obstacles:

- ``hide`` (probability 1/2): a box centred on a claimed-occupied voxel within 3 m of the
  straight start-goal segment, 0.6-2.0 m a side horizontally and 1-3 m tall (clipped to the world
  bounds); the server reports everything in it free (the dangerous lie);
- ``shift`` (1/4): the same kind of box, its claimed obstacles reported 0.3-1.5 m away
  horizontally;
- ``phantom`` (1/4): a box 0.4-1.2 m a side horizontally and 0.6-2 m tall centred on the
  start-goal segment (20-80 % along it), clear of the start and the goal by the body radius plus
  0.3 m, claimed occupied.

Variant ``i`` is a pure function of (base, seed, i): its generator is
``np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(i,)))``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from secure3d.geometry.polytope import polyline_distance
from secure3d.world.families import Family
from secure3d.world.spec import Attack, Region, Scenario

#: Claimed-occupied voxels farther than this from the start-goal segment (m) are not attacked
#: (an attack far from the route changes nothing); if none is that close, all are candidates.
NEAR_ROUTE = 3.0
#: Clearance kept between a phantom and the start/goal, on top of the body radius (m).
PHANTOM_CLEARANCE = 0.3


@dataclass(frozen=True, eq=False)
class _Prepared:
    """Claimed-occupied voxel centres near the route, (n, 3), and the route's end points."""

    near: np.ndarray
    start: np.ndarray
    goal: np.ndarray


def prepare(base: Scenario) -> _Prepared:
    """Read the base's server map once (the expensive part) and keep what variants draw from."""
    from secure3d.world.attacks import belief_map

    occ = belief_map(base).claimed_voxels(True)
    start, goal = np.asarray(base.start.position), np.asarray(base.goal.position)
    if len(occ):
        d = polyline_distance(occ, np.array([start, goal]))
        near = occ[d <= NEAR_ROUTE] if np.any(d <= NEAR_ROUTE) else occ
    else:
        near = occ
    return _Prepared(near, start, goal)


def _box_around(centre: np.ndarray, half: np.ndarray, base: Scenario) -> tuple:
    b = base.world.bounds
    lo = np.maximum(centre - half, b.lo)
    hi = np.minimum(centre + half, b.hi)
    return tuple(float(x) for x in lo), tuple(float(x) for x in hi)


def _phantom(prep: _Prepared, base: Scenario, rng: np.random.Generator) -> Attack:
    keep = base.vehicle.body_radius + PHANTOM_CLEARANCE
    for _ in range(200):
        half = np.append(rng.uniform(0.2, 0.6, 2), rng.uniform(0.3, 1.0))
        centre = prep.start + rng.uniform(0.2, 0.8) * (prep.goal - prep.start)
        lo, hi = _box_around(centre, half, base)
        gap = np.maximum(np.subtract(lo, [prep.start, prep.goal]), 0) + np.maximum(
            np.subtract([prep.start, prep.goal], hi), 0
        )
        if np.all(np.linalg.norm(gap, axis=1) >= keep):
            return Attack("phantom", region=Region(lo, hi))
    lo, hi = _box_around(0.5 * (prep.start + prep.goal), np.full(3, 0.1), base)
    return Attack("phantom", region=Region(lo, hi))


def variant(prep: _Prepared, base: Scenario, rng: np.random.Generator, i: int) -> Scenario:
    """Variant ``i``: the base plus one random region attack (see the module docstring)."""
    u = rng.uniform()
    if u < 0.25 or not len(prep.near):
        attack = _phantom(prep, base, rng)
    else:
        centre = prep.near[int(rng.integers(len(prep.near)))]
        half = np.append(rng.uniform(0.3, 1.0, 2), rng.uniform(0.5, 1.5))
        lo, hi = _box_around(centre, half, base)
        if u < 0.75:
            attack = Attack("hide", region=Region(lo, hi))
        else:
            angle = rng.uniform(0, 2 * np.pi)
            by = rng.uniform(0.3, 1.5) * np.array([np.cos(angle), np.sin(angle), 0.0])
            attack = Attack("shift", offset=tuple(float(x) for x in by), region=Region(lo, hi))
    server = dataclasses.replace(base.server_map, attacks=(*base.server_map.attacks, attack))
    note = f"Variant {i}: the server map is tampered with: {attack.describe()}."
    return dataclasses.replace(
        base,
        name=f"{base.name}_region_{i:03d}",
        server_map=server,
        description=f"{base.description} {note}".strip(),
    )


def variant_rng(seed: int, i: int) -> np.random.Generator:
    """The shared convention's generator of variant ``i``."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(i,)))


REGION_ATTACKS = Family(
    name="region_attacks",
    description=(
        "one random region attack (hide 1/2, shift 1/4, phantom 1/4) on the base's server map,"
        " whatever its source (OctoMap, point cloud, mesh, named obstacles), near the route"
    ),
    prepare=prepare,
    variant=variant,
)
