"""Hidden fences: a row of slats across the route, with gaps the camera sees through but the body
cannot pass.

A real scan is full of such obstacles: railings, fences, shelving, the scan lines of a laser seen
from afar. Each slat is at least ``planner.min_obstacle_size`` thick (the size the safety guarantee
covers, docs/guarantees.md), and the gaps between slats are 30-90 % of the body's diameter, so the
camera sees the space behind the fence through them (it is sensed free) while the fence itself is
a wall to the robot. The variant tests that a view through a gap never makes the gap a route and
that sight lines through it are judged against the slats.

- **pickets**: vertical slats from the floor (the nearest surface under the route) up;
- **rails**: horizontal bars, one above the other, from the floor up (3D vehicles only).

The fence leaves a way past it as wide as the body plus :data:`WAY_CLEARANCE` and a map voxel on
either side (:func:`_way`; wider than the secure planner's footprint at rest). In half the variants
of a 3D vehicle it spans the corridor from wall to wall up to 0.5-1.5 body radii above the route,
and the way is over it; otherwise it stands floor to ceiling along 40-80 % of the corridor from the
wall nearer the route, and the way is beside it.
(A fence that closes the corridor is the ``deadend`` family's wall.) Every variant keeps the start
and goal clear and the goal reachable for the body on the placement grid (the checks of
:mod:`secure3d.world.thin_families`). Variant ``i`` is a pure function of ``(base, rng)``.
"""

from __future__ import annotations

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.world.families import Family
from secure3d.world.hidden_obstacles import _fresh_name
from secure3d.world.spec import Box, Scenario
from secure3d.world.thin_families import (
    MAX_ATTEMPTS,
    Placement,
    _above_below,
    _path_point,
    hidden_variant,
    placeable,
    prepare_placement,
    span_box,
)

#: Gaps between slats, as fractions of the body's diameter: the body cannot pass, the camera sees.
GAP_FRACTION = (0.3, 0.9)
#: Slat thickness, in multiples of ``planner.min_obstacle_size``.
SLAT_FACTOR = (1.0, 1.5)
#: Room (m) beside the body, on either side, in the way round or over a fence.
WAY_CLEARANCE = 0.15
#: Part of the corridor a floor-to-ceiling fence spans (from one wall), at most all but the way.
PARTIAL_SPAN = (0.4, 0.8)


def _slats(a: float, b: float, w: float, gap: float) -> list[tuple[float, float]]:
    """Intervals of slats ``w`` wide from ``a`` to ``b``, the first at ``a`` and the last ending
    at ``b``, evenly spaced with gaps of at most ``gap``: [(start, end), ...]."""
    length = b - a
    if length < w:
        return []
    n = max(int(np.ceil((length - w) / (w + gap))) + 1, 2 if length >= 2 * w else 1)
    starts = a + np.linspace(0.0, length - w, n)
    return [(float(s), float(s + w)) for s in starts]


def _way(base: Scenario) -> float:
    """Width (m) of the way round (or over) a fence leaves: the body and :data:`WAY_CLEARANCE` on
    either side, and a map voxel on either side for the walls' voxels (wider than the secure
    planner's footprint at rest: 0.315 m a side for the shipped quadrotor)."""
    r = base.vehicle.body_radius
    return 2.0 * (r + WAY_CLEARANCE) + 2.0 * base.server_map.resolution


def _panel(
    prep: Placement, base: Scenario, rng: np.random.Generator
) -> tuple[str, list[tuple[np.ndarray, np.ndarray]]] | None:
    """One candidate fence (kind, its slats' (lo, hi)) across the body's path: floor to ceiling
    along part of the corridor, leaving a way round beside it, or (3D vehicles) a low fence across
    all of it, leaving a way over."""
    p, axis = _path_point(prep, rng)
    r = base.vehicle.body_radius
    w = base.planner.min_obstacle_size * rng.uniform(*SLAT_FACTOR)
    gap = 2.0 * r * rng.uniform(*GAP_FRACTION)
    planar = prep.grid.free.shape[2] == 1
    floor, ceiling = _above_below(prep, base, p)
    over = not planar and rng.random() < 0.5
    top = min(ceiling, p[2] + rng.uniform(0.5, 1.5) * r) if over else ceiling
    span = span_box(prep, base, p, axis, w / 2, (floor, top))
    if span is None or not top > floor or (over and ceiling - top < _way(base)):
        return None
    lo, hi = span
    a, b = float(lo[axis]), float(hi[axis])
    if not over:  # from the wall nearer the route, across it, leaving a way round beside it
        reach = min(p[axis] - a, b - p[axis]) + r  # the wall to the far side of the body
        cut = max((b - a) * rng.uniform(*PARTIAL_SPAN), reach)
        if cut > b - a - _way(base):
            return None
        a, b = (a, a + cut) if p[axis] - a <= b - p[axis] else (b - cut, b)
    kind = "pickets" if planar or rng.random() < 0.5 else "rails"
    boxes = []
    if kind == "pickets":
        for s, e in _slats(a, b, w, gap):
            blo, bhi = lo.copy(), hi.copy()
            blo[axis], bhi[axis] = s, e
            boxes.append((blo, bhi))
    else:
        for s, e in _slats(floor, top, w, gap):
            blo, bhi = lo.copy(), hi.copy()
            blo[axis], bhi[axis], blo[2], bhi[2] = a, b, s, e
            boxes.append((blo, bhi))
    return (kind, boxes) if boxes else None


def fence_placeable(
    prep: Placement, base: Scenario, boxes: list[tuple[np.ndarray, np.ndarray]]
) -> bool:
    """Whether the fence as a whole (the box around its slats) keeps the start and goal clear and
    leaves no sliver gap to the world's obstacles (the gaps between its own slats are the point),
    and the goal stays reachable for the body with every slat in place."""
    los, his = np.array([b[0] for b in boxes]), np.array([b[1] for b in boxes])
    if not np.all(his > los):
        return False
    return placeable(prep, base, los.min(axis=0), his.max(axis=0), parts=(los, his))


def prepare_fence(base: Scenario) -> Placement:
    """:func:`~secure3d.world.thin_families.prepare_placement`, refusing (once, before any run) a
    base where no fence fits: one with a way past it (:func:`_way`) in none of
    :data:`~secure3d.world.thin_families.MAX_ATTEMPTS` draws."""
    prep = prepare_placement(base)
    rng = np.random.default_rng(0)
    for _ in range(MAX_ATTEMPTS):
        cand = _panel(prep, base, rng)
        if cand is not None and fence_placeable(prep, base, cand[1]):
            return prep
    raise ScenarioError(_no_fence(base))


def _no_fence(base: Scenario) -> str:
    return (
        f"{base.name}: could not place a hidden fence in {MAX_ATTEMPTS} attempts (a fence across"
        f" the route must leave a way round or over it {_way(base):.2f} m wide: the corridors"
        " are too narrow; try --kind thin)"
    )


def fence_variant(prep: Placement, base: Scenario, rng: np.random.Generator, i: int) -> Scenario:
    """Variant ``i`` of :data:`FENCES` (pure in its inputs)."""
    for _ in range(MAX_ATTEMPTS):
        cand = _panel(prep, base, rng)
        if cand is None or not fence_placeable(prep, base, cand[1]):
            continue
        kind, slats = cand
        added: list[Box] = []
        for lo, hi in slats:
            name = _fresh_name(base.world, added, f"hidden_{kind}")
            added.append(Box(name, tuple(map(float, lo)), tuple(map(float, hi))))
        return hidden_variant(base, f"fence of {len(added)} {kind}", added, i, "fence")
    raise ScenarioError(_no_fence(base))


FENCES = Family(
    name="fence",
    description=(
        "one hidden fence across the route: pickets or rails at least planner.min_obstacle_size"
        " thick, gaps 30-90 % of the body's diameter (seen through, not passable)"
    ),
    prepare=prepare_fence,
    variant=fence_variant,
)
