"""Adversarial scenario families of issue 16: thin obstacles and 3D occlusion, hidden from the server.

Each family turns any base scenario into random variants with one hidden obstacle across the
shortest start-goal path of the body in the true world (the placement grid of
:func:`secure3d.world.attacks.random_hidden_obstacle_scenarios`):

- :data:`THIN_OBSTACLES`: a pole (vertical), plank (horizontal board) or wire (horizontal bar) at
  least ``planner.min_obstacle_size`` thick and at most twice that: the smallest obstacles the
  safety guarantee covers (docs/guarantees.md);
- :data:`OCCLUSION_3D`: a beam across the route, a ledge hanging from above (the route must duck
  under it) or a step rising from below (the route must climb over it), with the camera's vertical
  field of view narrowed to 30-60 deg in half of the variants: obstacles only a 3D view reveals.

A planar vehicle (the diff drive) is placed on one layer of cells at its height: it cannot pass
over or under an obstacle, so its thin variants are poles or leave it a way round, and
:data:`OCCLUSION_3D` refuses it.

Variant ``i`` is a pure function of ``(base, rng)``; the campaign draws ``rng`` as
``np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(i,)))``. Every variant keeps the
goal reachable for the body (checked on the placement grid) and keeps the start and goal clear.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.world.families import Family
from secure3d.world.hidden_obstacles import (
    PLACEMENT_CLEARANCE,
    _clear,
    _column_box,
    _connected,
    _fresh_name,
    _Grid,
    _nearest_free,
    _placement_grid,
)
from secure3d.world.spec import Attack, Box, Scenario
from secure3d.world.truth import true_obstacles

#: Placement tries per variant before giving up.
MAX_ATTEMPTS = 300
#: Part of the path (fraction of its length) on which the obstacle is placed: away from the start
#: region (observed before take-off) and from the goal.
PATH_SPAN = (0.25, 0.85)
#: Narrowed vertical fields of view (deg) of half the 3D-occlusion variants.
NARROW_VFOV_DEG = (30.0, 60.0)


@dataclass(frozen=True, eq=False)
class Placement:
    """Per-base work shared by all variants: the body's free grid and shortest path (k, 3), the
    true obstacles' boxes (m, 3), which of them a new obstacle may touch, and start/goal cells."""

    grid: _Grid
    path: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    touchable: np.ndarray
    start_cell: np.ndarray
    goal_cell: np.ndarray


def prepare_placement(base: Scenario) -> Placement:
    """The placement grid and path of ``base`` (raises :class:`ScenarioError` if it has no path)."""
    obstacles = true_obstacles(base)
    grid, path = _placement_grid(base, obstacles)
    lo, hi = obstacles.aabbs()
    touchable = np.arange(len(lo)) < len(lo) - len(obstacles.voxel_boxes)
    a = _nearest_free(grid, np.array(base.start.position), grid.free)
    g = _nearest_free(grid, np.array(base.goal.position), grid.free)
    if a is None or g is None:
        raise ScenarioError(f"{base.name}: start or goal is not on the placement grid")
    return Placement(grid, path, lo, hi, touchable, a, g)


def _path_point(prep: Placement, rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """A point of the middle of the path and the horizontal axis (0: x, 1: y) most across it."""
    p = prep.path
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    pick = np.flatnonzero((s >= PATH_SPAN[0] * s[-1]) & (s <= PATH_SPAN[1] * s[-1]))
    k = int(rng.choice(pick if len(pick) else np.arange(len(p))))
    tangent = p[min(k + 1, len(p) - 1)] - p[max(k - 1, 0)]
    across = 0 if abs(tangent[0]) < abs(tangent[1]) else 1
    return p[k].copy(), across


def span_box(
    prep: Placement, base: Scenario, centre: np.ndarray, axis: int, half: float, z: tuple
) -> tuple[np.ndarray, np.ndarray] | None:
    """A box through ``centre`` spanning horizontal ``axis`` from the nearest obstacle face on one
    side to the nearest on the other (or the bounds), ``2 half`` deep along the other horizontal
    axis, between heights ``z``; None if ``centre`` lies inside an obstacle of that band."""
    other = 1 - axis
    lo, hi = prep.lo, prep.hi
    band = (
        (lo[:, other] < centre[other] + half)
        & (hi[:, other] > centre[other] - half)
        & (lo[:, 2] < z[1])
        & (hi[:, 2] > z[0])
    )
    c = centre[axis]
    if np.any(band & (lo[:, axis] < c) & (hi[:, axis] > c)):
        return None
    b = base.world.bounds
    box_lo, box_hi = np.array(centre, float), np.array(centre, float)
    box_lo[axis] = hi[band & (hi[:, axis] <= c), axis].max(initial=b.lo[axis])
    box_hi[axis] = lo[band & (lo[:, axis] >= c), axis].min(initial=b.hi[axis])
    box_lo[other], box_hi[other] = centre[other] - half, centre[other] + half
    box_lo[2], box_hi[2] = z
    return box_lo, box_hi


def _above_below(prep: Placement, base: Scenario, centre: np.ndarray) -> tuple[float, float]:
    """Heights of the nearest obstacle face under and over ``centre`` (or the bounds)."""
    col = _column_box(
        centre,
        np.full(2, 1e-3),
        prep.lo,
        prep.hi,
        (base.world.bounds.lo[2], base.world.bounds.hi[2]),
    )
    return float(col[0][2]), float(col[1][2])


def _thin_box(
    prep: Placement, base: Scenario, rng: np.random.Generator
) -> tuple[str, tuple] | None:
    """One candidate thin obstacle (kind, (lo, hi)) cutting the body's path."""
    p, axis = _path_point(prep, rng)
    r = base.vehicle.body_radius
    w = base.planner.min_obstacle_size * rng.uniform(1.0, 2.0)
    kind = str(rng.choice(["pole", "plank", "wire"]))
    if kind == "pole":
        centre = p.copy()
        centre[axis] += rng.uniform(-0.8, 0.8) * r
        box = _column_box(centre, np.full(2, w / 2), prep.lo, prep.hi, _z_range(base))
        return kind, box
    zc = p[2] + rng.uniform(-0.8, 0.8) * r
    if kind == "plank":
        depth = rng.uniform(2.0, 6.0) * w  # a board: w thick, several w wide
        return kind, span_box(prep, base, p, axis, depth / 2, (zc - w / 2, zc + w / 2))
    return kind, span_box(prep, base, p, axis, w / 2, (zc - w / 2, zc + w / 2))


def _occlusion_box(
    prep: Placement, base: Scenario, rng: np.random.Generator
) -> tuple[str, tuple] | None:
    """One candidate 3D-occlusion obstacle (kind, (lo, hi)) cutting the body's path."""
    p, axis = _path_point(prep, rng)
    r = base.vehicle.body_radius
    depth = rng.uniform(0.2, 0.6)
    kind = str(rng.choice(["beam", "ledge", "step"]))
    floor, ceiling = _above_below(prep, base, p)
    if kind == "beam":
        t = rng.uniform(0.1, 0.4)
        zc = p[2] + rng.uniform(-0.8, 0.8) * r
        z = (zc - t / 2, zc + t / 2)
    elif kind == "ledge":
        z = (p[2] + rng.uniform(-0.8, 0.5) * r, ceiling)
    else:
        z = (floor, p[2] + rng.uniform(-0.5, 0.8) * r)
    if not z[0] < z[1]:
        return None
    return kind, span_box(prep, base, p, axis, depth / 2, z)


def _z_range(base: Scenario) -> tuple[float, float]:
    return float(base.world.bounds.lo[2]), float(base.world.bounds.hi[2])


def placeable(
    prep: Placement,
    base: Scenario,
    lo: np.ndarray,
    hi: np.ndarray,
    parts: tuple[np.ndarray, np.ndarray] | None = None,
) -> bool:
    """Whether a hidden box [lo, hi] keeps the start and the goal clear (body radius plus
    :data:`PLACEMENT_CLEARANCE`) and the goal reachable from the start on the placement grid.
    ``parts``: the boxes (k, 3) that make up an obstacle whose outline is [lo, hi] (a fence's
    slats); they, not the outline, block the grid."""
    keep = base.vehicle.body_radius + PLACEMENT_CLEARANCE
    ends = np.array([base.start.position, base.goal.position])
    if not np.all(hi > lo) or not _clear(
        (lo, hi), prep.lo, prep.hi, prep.touchable, ends, keep, closed=keep
    ):
        return False
    los, his = parts if parts is not None else (lo[None], hi[None])
    trial = prep.grid.blocked_by(los, his) & prep.grid.free
    return bool(_connected(trial, prep.start_cell, prep.goal_cell))


def place_hidden(
    prep: Placement,
    base: Scenario,
    rng: np.random.Generator,
    draw: Callable[[Placement, Scenario, np.random.Generator], tuple[str, tuple] | None],
) -> tuple[str, Box]:
    """Draw candidates until one keeps start and goal clear and the goal reachable."""
    for _ in range(MAX_ATTEMPTS):
        cand = draw(prep, base, rng)
        if cand is None or cand[1] is None:
            continue
        kind, (lo, hi) = cand
        if placeable(prep, base, lo, hi):
            name = _fresh_name(base.world, [], f"hidden_{kind}")
            return kind, Box(name, tuple(map(float, lo)), tuple(map(float, hi)))
    raise ScenarioError(
        f"{base.name}: could not place a hidden obstacle in {MAX_ATTEMPTS} attempts"
    )


def hidden_variant(
    base: Scenario, kind: str, box: Box | Sequence[Box], i: int, family: str
) -> Scenario:
    """``base`` with the obstacle ``box`` (or the boxes of one obstacle) in the true world and
    absent from the server's map, named ``{base}_{family}_{i:03d}``."""
    boxes = (box,) if isinstance(box, Box) else tuple(box)
    names = tuple(b.name for b in boxes)
    world = dataclasses.replace(base.world, boxes=(*base.world.boxes, *boxes))
    server = base.server_map
    if server.from_world:
        hide = tuple(Attack("hide", target=n) for n in names)
        server = dataclasses.replace(server, attacks=(*server.attacks, *hide))
    else:  # a server map file (OctoMap, cloud, mesh) or survey lacks it as it is: say so
        server = dataclasses.replace(server, lacks=(*server.lacks, *names))
    size = np.max([b.hi for b in boxes], axis=0) - np.min([b.lo for b in boxes], axis=0)
    what = names[0] if len(names) == 1 else f"{names[0]} .. {names[-1]}"
    note = (
        f"Variant {i} of {family}: hidden {kind} {what}"
        f" ({size[0]:.2f} x {size[1]:.2f} x {size[2]:.2f} m)."
    )
    return dataclasses.replace(
        base,
        name=f"{base.name}_{family}_{i:03d}",
        world=world,
        server_map=server,
        description=f"{base.description} {note}".strip(),
    )


def thin_variant(prep: Placement, base: Scenario, rng: np.random.Generator, i: int) -> Scenario:
    """Variant ``i`` of :data:`THIN_OBSTACLES` (pure in its inputs)."""
    kind, box = place_hidden(prep, base, rng, _thin_box)
    return hidden_variant(base, kind, box, i, "thin")


def prepare_occlusion(base: Scenario) -> Placement:
    """:func:`prepare_placement`, for a vehicle that moves in 3D: a beam, ledge or step spans the
    route, so a planar vehicle (on one layer of cells) could never pass it."""
    prep = prepare_placement(base)
    if prep.grid.free.shape[2] == 1:
        raise ScenarioError(
            f"{base.name}: family occlusion3d needs a vehicle that moves in 3D (its beams, ledges"
            f" and steps span the route, which a planar {base.vehicle.model} cannot pass over or"
            " under); try --kind thin"
        )
    return prep


def occlusion_variant(
    prep: Placement, base: Scenario, rng: np.random.Generator, i: int
) -> Scenario:
    """Variant ``i`` of :data:`OCCLUSION_3D` (pure in its inputs)."""
    kind, box = place_hidden(prep, base, rng, _occlusion_box)
    out = hidden_variant(base, kind, box, i, "occlusion3d")
    if rng.random() < 0.5 and np.degrees(base.camera.vfov) > NARROW_VFOV_DEG[0]:
        top = min(NARROW_VFOV_DEG[1], float(np.degrees(base.camera.vfov)))
        camera = dataclasses.replace(
            base.camera, vfov_deg=float(rng.uniform(NARROW_VFOV_DEG[0], top))
        )
        out = dataclasses.replace(out, camera=camera)
    return out


THIN_OBSTACLES = Family(
    name="thin",
    description=(
        "one hidden pole, plank or wire across the route, 1-2x planner.min_obstacle_size thick"
    ),
    prepare=prepare_placement,
    variant=thin_variant,
)

OCCLUSION_3D = Family(
    name="occlusion3d",
    description=(
        "one hidden beam, ledge (from above) or step (from below) across the route; half the"
        " variants with a 30-60 deg vertical field of view"
    ),
    prepare=prepare_occlusion,
    variant=occlusion_variant,
)
