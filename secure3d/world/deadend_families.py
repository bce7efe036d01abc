"""The dead-end family: a hidden wall closes the corridor of the shortest route (issue 16).

Variant ``i`` of a base scenario adds one hidden wall, 0.1-0.3 m thick and as tall as the world,
across the base's shortest start-goal path of the body in the true world, at a random point of the
middle of the path (35-85 % of its length), spanning the corridor from the nearest obstacle face on
one side to the nearest on the other. The goal must stay reachable for the body, so the base needs
a second route: the robot must see the dead end while it can still stop, then turn round (or
reverse, for a differential drive) on a certified plan and take the other route. Bases with a
single route raise :class:`~secure3d.errors.ScenarioError` naming the base.

Variant ``i`` is a pure function of ``(base, rng)``, like every family (:mod:`.families`).
"""

from __future__ import annotations

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.world.families import Family
from secure3d.world.spec import Scenario
from secure3d.world.thin_families import (
    Placement,
    hidden_variant,
    place_hidden,
    prepare_placement,
    span_box,
)

__all__ = ["DEAD_END"]

#: Wall thickness range (m) and the part of the path (fraction of its length) it is placed on.
THICKNESS = (0.1, 0.3)
SPAN = (0.35, 0.85)


def _wall(
    prep: Placement, base: Scenario, rng: np.random.Generator
) -> tuple[str, tuple[np.ndarray, np.ndarray] | None] | None:
    """One candidate wall (kind, (lo, hi)) across the corridor at a point of the path."""
    p = prep.path
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    pick = np.flatnonzero((s >= SPAN[0] * s[-1]) & (s <= SPAN[1] * s[-1]))
    if not len(pick):
        return None
    k = int(rng.choice(pick))
    tangent = p[min(k + 1, len(p) - 1)] - p[max(k - 1, 0)]
    across = 0 if abs(tangent[0]) < abs(tangent[1]) else 1
    z = (float(base.world.bounds.lo[2]), float(base.world.bounds.hi[2]))
    half = 0.5 * rng.uniform(*THICKNESS)
    return "dead_end", span_box(prep, base, p[k], across, half, z)


def dead_end_variant(prep: Placement, base: Scenario, rng: np.random.Generator, i: int) -> Scenario:
    """Variant ``i`` of :data:`DEAD_END` (pure in its inputs)."""
    try:
        kind, box = place_hidden(prep, base, rng, _wall)
    except ScenarioError as exc:
        raise ScenarioError(
            f"{exc}: every wall across the middle of its shortest route cut the goal off; the "
            "deadend family needs a base with a second route round the wall"
        ) from exc
    return hidden_variant(base, kind, box, i, "deadend")


DEAD_END = Family(
    name="deadend",
    description=(
        "one hidden wall, as tall as the world, across the corridor of the shortest route: the"
        " robot must stop, turn round and take another route (the base needs two)"
    ),
    prepare=prepare_placement,
    variant=dead_end_variant,
)
