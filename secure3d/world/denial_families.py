"""The denial-of-service family: a claimed wall across the whole world closes every route.

Variant ``i`` of a base scenario adds one region ``phantom`` to its server map: a slab 0.2-0.6 m
thick, across the base's shortest start-goal path of the body at a random point of its middle
(25-85 % of its length), perpendicular to the path there, and spanning the world's bounds in the
other two axes, so the belief map shows no route at all until the camera has looked at the slab.
Where the slab is out of the camera's sight from the start, the robot must go and look
(:mod:`secure3d.simulation.explore`); the slab does not exist, so it never costs safety, only time.
The start and the goal are kept at least 0.5 m from the slab.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.world.families import Family
from secure3d.world.spec import Attack, Region, Scenario
from secure3d.world.thin_families import PATH_SPAN, Placement, prepare_placement

__all__ = ["DENIAL"]

#: Slab thickness range (m), and the least distance of the start and the goal from it (m).
THICKNESS = (0.2, 0.6)
KEEP_CLEAR = 0.5
#: Draws per variant before giving up.
MAX_ATTEMPTS = 200


def _slab(prep: Placement, base: Scenario, rng: np.random.Generator) -> Region | None:
    """One random slab across the path, or None if it comes too near the start or the goal."""
    p = prep.path
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    pick = np.flatnonzero((s >= PATH_SPAN[0] * s[-1]) & (s <= PATH_SPAN[1] * s[-1]))
    k = int(rng.choice(pick if len(pick) else np.arange(len(p))))
    tangent = p[min(k + 1, len(p) - 1)] - p[max(k - 1, 0)]
    axis = int(np.argmax(np.abs(tangent)))
    half = 0.5 * rng.uniform(*THICKNESS)
    lo = np.array(base.world.bounds.lo, dtype=float)
    hi = np.array(base.world.bounds.hi, dtype=float)
    lo[axis], hi[axis] = p[k, axis] - half, p[k, axis] + half
    for end in (base.start.position, base.goal.position):
        if abs(float(end[axis]) - p[k, axis]) < half + KEEP_CLEAR:
            return None
    return Region(tuple(lo.tolist()), tuple(hi.tolist()))


def denial_variant(prep: Placement, base: Scenario, rng: np.random.Generator, i: int) -> Scenario:
    """Variant ``i``: ``base`` with a claimed slab across its route (see the module doc)."""
    for _ in range(MAX_ATTEMPTS):
        region = _slab(prep, base, rng)
        if region is not None:
            attacks = (*base.server_map.attacks, Attack("phantom", region=region))
            server = dataclasses.replace(base.server_map, attacks=attacks)
            return dataclasses.replace(base, name=f"{base.name}_denial_{i:03d}", server_map=server)
    raise ScenarioError(f"{base.name}: no slab across the route keeps the start and goal clear")


DENIAL = Family(
    name="denial",
    description=(
        "a claimed (phantom) slab across the whole world at a random point of the route: the map"
        " shows no route until the robot looks"
    ),
    prepare=prepare_placement,
    variant=denial_variant,
)
