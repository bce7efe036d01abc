"""The dead-end family: a hidden wall closes the corridor of the shortest route (issue 16).

Variant ``i`` of a base scenario adds one hidden wall, 0.1-0.3 m thick and as tall as the world,
across the base's shortest start-goal path of the body in the true world, at a random point of the
middle of the path (35-85 % of its length), spanning the corridor from the nearest obstacle face on
one side to the nearest on the other. The goal must stay reachable for the body, so the base needs
a second route: the robot must see the dead end while it can still stop, then turn round (or
reverse, for a differential drive) on a certified plan and take the other route. A base with a
single route is refused once, when the family is prepared (:func:`prepare_dead_end`: no wall at
any of :data:`PROBES` places along the middle of the path keeps the goal reachable), with a
:class:`~secure3d.errors.ScenarioError` naming the base, instead of once per variant.

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
    placeable,
    prepare_placement,
    span_box,
)

__all__ = ["DEAD_END", "prepare_dead_end"]

#: Wall thickness range (m) and the part of the path (fraction of its length) it is placed on.
THICKNESS = (0.1, 0.3)
SPAN = (0.35, 0.85)
#: Places along the middle of the path where :func:`prepare_dead_end` tries a wall.
PROBES = 24


def _wall(
    prep: Placement, base: Scenario, rng: np.random.Generator
) -> tuple[str, tuple[np.ndarray, np.ndarray] | None] | None:
    """One candidate wall (kind, (lo, hi)) across the corridor at a point of the path."""
    pick = _middle(prep.path)
    if not len(pick):
        return None
    k = int(rng.choice(pick))
    return "dead_end", _wall_at(prep, base, k, 0.5 * rng.uniform(*THICKNESS))


def _middle(p: np.ndarray) -> np.ndarray:
    """Indices of the path points (n, 3) in the :data:`SPAN` part of its length."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    return np.flatnonzero((s >= SPAN[0] * s[-1]) & (s <= SPAN[1] * s[-1]))


def _wall_at(
    prep: Placement, base: Scenario, k: int, half: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """The wall ``2 half`` thick across the corridor at path point ``k``, as tall as the world."""
    p = prep.path
    tangent = p[min(k + 1, len(p) - 1)] - p[max(k - 1, 0)]
    across = 0 if abs(tangent[0]) < abs(tangent[1]) else 1
    z = (float(base.world.bounds.lo[2]), float(base.world.bounds.hi[2]))
    return span_box(prep, base, p[k], across, half, z)


def prepare_dead_end(base: Scenario) -> Placement:
    """The placement of ``base`` (:func:`~.thin_families.prepare_placement`), refused with a
    :class:`ScenarioError` if no wall of the thinnest kind at any of :data:`PROBES` places along
    the middle of the shortest route keeps the goal reachable: the base has a single route."""
    prep = prepare_placement(base)
    pick = _middle(prep.path)
    probes = (
        pick[np.unique(np.linspace(0, len(pick) - 1, PROBES).astype(int))] if len(pick) else pick
    )
    for k in probes:
        box = _wall_at(prep, base, int(k), 0.5 * THICKNESS[0])
        if box is not None and placeable(prep, base, *box):
            return prep
    raise ScenarioError(
        f"{base.name}: every wall across the middle of its shortest route cuts the goal off"
        f" ({len(probes)} places tried); the deadend family needs a base with a second route"
        " round the wall; try --kind thin"
    )


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
    prepare=prepare_dead_end,
    variant=dead_end_variant,
)
