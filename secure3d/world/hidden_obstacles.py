"""Random hidden obstacles: variants of a scenario with extra true obstacles that the server hides,
placed where they matter (across the start-goal path, at a corner), for collision-rate campaigns.

Re-exported by :mod:`secure3d.world.attacks`.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.validation import is_int_in, is_real
from secure3d.world.spec import Attack, Box, Scenario, World, box_distance
from secure3d.world.truth import TrueObstacles, true_obstacles

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.world.families import Family

__all__ = [
    "GAP_ALLOWANCE",
    "PLACEMENT_CLEARANCE",
    "hidden_obstacle_family",
    "random_hidden_obstacle_scenarios",
]

#: Extra distance (m), on top of the body radius, kept between a generated hidden obstacle and the
#: start, the goal and the obstacles beside it that it does not touch: no gap is so narrow that
#: only a needle-threading path fits.
PLACEMENT_CLEARANCE = 0.3
#: A gap left beside a generated obstacle is also at least the body's diameter plus one map voxel on
#: each side (a sensed surface marks the voxel in front of it) plus this allowance (m): narrower
#: gaps are closed in any voxel map of that resolution, so no sound planner could use them.
GAP_ALLOWANCE = 0.1
#: Cell budget of the placement grid: fine enough for 0.5 m corridors in a 20 m world while a
#: shortest-path search on it takes well under a second.
_GRID_CELLS = 200_000
#: A path that strays from the straight start-goal line by more than this fraction of its length
#: goes round a corner (an L-corridor strays ~40 %, a path through a forest a few %).
_TURN_DEVIATION = 0.15
#: Finest placement grid cell (m), tried when the coarse grid closes a narrow passage.
_MIN_CELL = 0.025
#: Largest grid the refinement may reach; beyond it the search gets slow and memory-hungry.
_MAX_GRID_CELLS = 3_000_000


# --------------------------------------------------------------------------------------------
# Random hidden obstacles
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Grid:
    """Free cells of the world for a body of radius r: centres outside every inflated AABB."""

    free: np.ndarray  # (nx, ny, nz) bool
    origin: np.ndarray  # (3,) centre of cell (0, 0, 0)
    cell: float
    inflate: float

    def centres(self, idx: np.ndarray) -> np.ndarray:
        return self.origin + idx * self.cell

    def blocked_by(self, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """A copy of ``free`` with cells inside the inflated boxes ``lo``, ``hi`` (k, 3) cleared."""
        free = self.free.copy()
        shape = np.array(free.shape)
        i0 = np.clip(np.ceil((lo - self.inflate - self.origin) / self.cell), 0, shape).astype(int)
        i1 = np.clip(np.floor((hi + self.inflate - self.origin) / self.cell) + 1, 0, shape)
        for a, b in zip(i0, i1.astype(int), strict=True):  # one slice per obstacle, not per cell
            free[a[0] : b[0], a[1] : b[1], a[2] : b[2]] = False
        return free


def plane_height(scenario: Scenario) -> float | None:
    """The height a planar vehicle (one that moves at a fixed height, like the diff drive) lives
    at (its start's z, which the scenario's checks tie to ``vehicle.limits.height``); None for a
    vehicle that moves in 3D."""
    from secure3d.dynamics import model_from_spec

    model = model_from_spec(scenario.vehicle, scenario.camera)
    return float(scenario.start.position[2]) if model.planar else None


def _make_grid(
    scenario: Scenario, lo: np.ndarray, hi: np.ndarray, cell: float, height: float | None = None
) -> _Grid:
    """The free cells for the body: a 3D grid, or with ``height`` one layer of cells at that height
    (a planar vehicle cannot pass over or under an obstacle)."""
    b = scenario.world.bounds
    r = scenario.vehicle.body_radius
    blo, bhi = np.add(b.lo, r), np.subtract(b.hi, r)
    if height is not None:
        blo[2] = bhi[2] = height
    shape = np.maximum(np.floor((bhi - blo) / cell).astype(int) + 1, 1)
    origin = blo + 0.5 * ((bhi - blo) - (shape - 1) * cell)
    grid = _Grid(np.ones(tuple(shape), dtype=bool), origin, cell, r)
    return dataclasses.replace(grid, free=grid.blocked_by(lo, hi))


def _nearest_free(grid: _Grid, p: np.ndarray, free: np.ndarray) -> np.ndarray | None:
    idx = np.argwhere(free)
    if not len(idx):
        return None
    d = np.linalg.norm(grid.centres(idx) - p, axis=1)
    k = int(np.argmin(d))
    return idx[k] if d[k] <= 2.0 * grid.cell + grid.inflate else None


def _connected(free: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    from scipy import ndimage

    labels, _ = ndimage.label(free, structure=np.ones((3, 3, 3), dtype=bool))
    return bool(labels[tuple(a)] != 0 and labels[tuple(a)] == labels[tuple(b)])


def _shortest_path(grid: _Grid, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    """Cell centres (k, 3) of a shortest 26-connected path from cell ``a`` to ``b``, or None."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    free = grid.free
    ids = -np.ones(free.shape, dtype=np.int64)
    ids[free] = np.arange(int(free.sum()))
    offsets = [o for o in np.ndindex(3, 3, 3) if o > (1, 1, 1)]  # half of the 26 neighbours
    rows, cols, weights = [], [], []
    n = np.array(free.shape)
    for off in offsets:
        d = np.array(off) - 1
        src = tuple(slice(max(0, -k), m - max(0, k)) for k, m in zip(d, n, strict=True))
        dst = tuple(slice(max(0, k), m - max(0, -k)) for k, m in zip(d, n, strict=True))
        both = free[src] & free[dst]
        rows.append(ids[src][both])
        cols.append(ids[dst][both])
        weights.append(np.full(int(both.sum()), np.linalg.norm(d) * grid.cell))
    count = int(free.sum())
    graph = coo_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
        shape=(count, count),
    ).tocsr()
    dist, pred = dijkstra(
        graph, directed=False, indices=int(ids[tuple(a)]), return_predecessors=True
    )
    target = int(ids[tuple(b)])
    if not np.isfinite(dist[target]):
        return None
    chain = [target]
    while chain[-1] != int(ids[tuple(a)]):
        chain.append(int(pred[chain[-1]]))
    cells = np.argwhere(free)[np.array(chain[::-1])]
    return grid.centres(cells)


def _segments_blocked(p0: np.ndarray, p1: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """For segments ``p0 -> p1[i]`` (p1 : (k, 3)), whether any box ``lo``/``hi`` (m, 3) cuts them.

    Slab test, vectorised over segments x boxes (boxes in chunks, to bound memory on voxel
    worlds). Returns (k,) bool.
    """
    d = p1[:, None, :] - p0  # (k, 1, 3)
    blocked = np.zeros(len(p1), dtype=bool)
    for start in range(0, len(lo), 4096):
        blo, bhi = lo[start : start + 4096], hi[start : start + 4096]
        with np.errstate(divide="ignore", invalid="ignore"):
            t0 = (blo[None] - p0) / d
            t1 = (bhi[None] - p0) / d
        inside = (p0 >= blo) & (p0 <= bhi)  # (m, 3): where d == 0 the slab is all or nothing
        t_near = np.where(d == 0, np.where(inside, -np.inf, np.inf), np.minimum(t0, t1))
        t_far = np.where(d == 0, np.where(inside, np.inf, -np.inf), np.maximum(t0, t1))
        enter = np.max(t_near, axis=2)
        leave = np.min(t_far, axis=2)
        blocked |= np.any((enter <= leave) & (leave > 1e-9) & (enter < 1.0 - 1e-9), axis=1)
    return blocked


def _placement_grid(scenario: Scenario, obstacles: TrueObstacles) -> tuple[_Grid, np.ndarray]:
    lo, hi = obstacles.aabbs()
    b = scenario.world.bounds
    r = scenario.vehicle.body_radius
    volume = float(np.prod(np.subtract(b.extent, 2 * r)))
    cell = float(np.clip((volume / _GRID_CELLS) ** (1 / 3), 0.05, 0.5))
    start, goal = np.array(scenario.start.position), np.array(scenario.goal.position)
    height = plane_height(scenario)
    while True:
        grid = _make_grid(scenario, lo, hi, cell, height)
        a = _nearest_free(grid, start, grid.free)
        g = _nearest_free(grid, goal, grid.free)
        path = None
        if a is not None and g is not None and _connected(grid.free, a, g):
            path = _shortest_path(grid, a, g)
        if path is not None:
            return grid, np.vstack([start, path, goal])
        finer = cell / 2
        if finer < _MIN_CELL or volume / finer**3 > _MAX_GRID_CELLS:
            raise ScenarioError(
                f"{scenario.name}: no collision-free path from start to goal in the true world"
                f" for body radius {r:g} m (searched down to {cell:.3g} m cells)"
            )
        cell = finer


def _candidates(
    path: np.ndarray, lo: np.ndarray, hi: np.ndarray, kind: str
) -> tuple[np.ndarray, str]:
    """Indices of path points where a hidden obstacle matters, and the kind actually used.

    ``"auto"`` picks ``"corner"`` when the path turns: it strays from the straight start-goal line
    by more than :data:`_TURN_DEVIATION` of that line's length (and at least 1 m) and part of it
    is hidden from the start. Clutter (a forest) also hides parts of the path, but the path stays
    close to the straight line.
    """
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    total = s[-1]
    if kind in ("corner", "auto"):
        occluded = (
            _segments_blocked(path[0], path, lo, hi) if len(lo) else np.zeros(len(path), bool)
        )
        chord = path[-1] - path[0]
        length = float(np.linalg.norm(chord))
        rel = path - path[0]
        along = rel @ chord / max(length**2, 1e-12)
        stray = np.linalg.norm(rel - along[:, None] * chord, axis=1).max()
        turns = stray > max(1.0, _TURN_DEVIATION * length)
        if np.any(occluded) and (kind == "corner" or turns):
            first = int(np.argmax(occluded))
            # "Just behind the corner": the first 2.5 m of path the start cannot see.
            pick = np.flatnonzero((s >= s[first]) & (s <= s[first] + 2.5))
            return pick, "corner"
    pick = np.flatnonzero((s >= 0.2 * total) & (s <= 0.85 * total))
    return (pick if len(pick) else np.arange(1, len(path) - 1)), "forest"


def random_hidden_obstacle_scenarios(
    base: Scenario,
    n: int,
    rng: np.random.Generator | int,
    kind: Literal["corner", "forest", "auto"] = "auto",
    count: int = 1,
    max_attempts: int = 500,
) -> list[Scenario]:
    """Variants of ``base`` with ``count`` extra true obstacles hidden from the server map.

    Each obstacle is a vertical prism placed across the shortest start-goal path of the body in the
    true world (found on a voxel grid), standing on whatever is below it (floor, desk, or the
    bottom of the world) and reaching whatever is above it (ceiling, or the top of the world):

    - ``"corner"``: within the first 2.5 m of path that the start cannot see (just behind the
      first blind corner), footprint 0.4-1.2 m a side (a crate, a cabinet);
    - ``"forest"``: anywhere on the middle of the path, footprint 0.2-0.5 m (a tree trunk);
    - ``"auto"``: ``"corner"`` when the path has a blind part, else ``"forest"``.

    The obstacle cuts the path (it lies within the body radius of a path point), keeps the body
    radius + :data:`PLACEMENT_CLEARANCE` (and at least the body diameter + two map voxels +
    :data:`GAP_ALLOWANCE`) from the start, the goal and every obstacle beside it (all but those it
    stands on or reaches up to) unless it touches that obstacle (a crate against a wall; never
    against OctoMap voxels), and leaves the goal reachable.

    Parameters
    ----------
    base : Scenario
    n : int
        Number of variants.
    rng : numpy Generator or int seed
        The only source of randomness: the same seed gives the same variants.
    kind : "corner", "forest" or "auto"
    count : int
        Hidden obstacles per variant.
    max_attempts : int
        Placement tries per obstacle before giving up.

    Returns
    -------
    list of Scenario
        Named ``<base>_hidden_<i>``. Each new box is added to ``world.boxes`` with a ``hide``
        attack (no attack when the server map is its own file, OctoMap, cloud or mesh: the file
        lacks it anyway).

    Raises
    ------
    ScenarioError
        No path from start to goal exists in ``base``, or no valid placement was found.
    """
    if kind not in ("corner", "forest", "auto"):
        raise ScenarioError(f"kind: must be one of corner, forest, auto (got {kind!r})")
    if not is_int_in(n, 0):
        raise ScenarioError(f"n: must be a non-negative integer (got {n!r})")
    if not is_int_in(count, 1):
        raise ScenarioError(f"count: must be a positive integer (got {count!r})")
    rng = np.random.default_rng(rng)
    placement = _HiddenPlacement.prepare(base, kind)
    return [placement.variant(base, rng, i, count, max_attempts) for i in range(n)]


@dataclass(frozen=True)
class _HiddenPlacement:
    """The per-base work of hidden-obstacle placement (the voxel path and candidate points), done
    once; :meth:`variant` then places one variant's obstacles from a generator."""

    grid: object
    path: np.ndarray
    lo0: np.ndarray
    hi0: np.ndarray
    touchable0: np.ndarray
    picks: np.ndarray
    used: str
    ends: np.ndarray
    a: object
    g: object
    half_range: tuple[float, float]
    keep: float
    #: the world holds voxel boxes (a scanned map): gaps to them are judged by the route, below
    rough: bool = False

    @classmethod
    def prepare(cls, base: Scenario, kind: str, footprint: float | None = None) -> _HiddenPlacement:
        """Find the start-goal path of ``base`` and where along it obstacles may go (``footprint``:
        see :func:`hidden_obstacle_family`)."""
        obstacles = true_obstacles(base)
        grid, path = _placement_grid(base, obstacles)
        lo0, hi0 = obstacles.aabbs()
        touchable0 = np.arange(len(lo0)) < len(lo0) - len(obstacles.voxel_boxes)
        picks, used = _candidates(path, lo0, hi0, kind)
        ends = np.array([base.start.position, base.goal.position])
        r = base.vehicle.body_radius
        return cls(
            grid=grid,
            path=path,
            lo0=lo0,
            hi0=hi0,
            touchable0=touchable0,
            picks=picks,
            used=used,
            ends=ends,
            a=_nearest_free(grid, ends[0], grid.free),
            g=_nearest_free(grid, ends[1], grid.free),
            half_range=(0.2, 0.6) if used == "corner" else (0.1, 0.25),
            keep=_keep(r, base.server_map.resolution, footprint),
            rough=bool(len(obstacles.voxel_boxes)),
        )

    def _try_box(
        self, base: Scenario, rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        path, r, b = self.path, base.vehicle.body_radius, base.world.bounds
        k = int(rng.choice(self.picks))
        tangent = path[min(k + 1, len(path) - 1)] - path[max(k - 1, 0)]
        across = np.cross(tangent, [0.0, 0.0, 1.0])
        if np.linalg.norm(across[:2]) < 1e-9:
            across = np.array([1.0, 0.0, 0.0])
        across /= np.linalg.norm(across)
        half = rng.uniform(*self.half_range, size=2)
        reach = abs(across[0]) * half[0] + abs(across[1]) * half[1]
        centre = path[k] + across * rng.uniform(-reach - 0.5 * r, reach + 0.5 * r)
        return _column_box(centre, half, lo, hi, (b.lo[2], b.hi[2]))

    def variant(
        self, base: Scenario, rng: np.random.Generator, i: int, count: int, max_attempts: int = 500
    ) -> Scenario:
        """Variant ``i``: ``count`` obstacles placed with draws from ``rng`` only."""
        lo, hi, touchable = self.lo0, self.hi0, self.touchable0
        free = self.grid.free
        # A scanned wall is rough: a box at least ``keep`` from every one of its voxels barely ever
        # fits in a scanned corridor (0 of 500 draws on geb079). There any gap to voxels is
        # accepted, and the route must keep ``keep`` from the new box instead: blocked for the
        # body with the box grown by ``keep - 2 r``, a gap beside it passes only if ``keep`` wide.
        closed = self.keep if self.rough else 0.0
        grow = max(self.keep - 2.0 * self.grid.inflate, 0.0) if self.rough else 0.0
        added: list[Box] = []
        for j in range(count):
            for _ in range(max_attempts):
                box = self._try_box(base, rng, lo, hi)
                if np.min(box[1] - box[0]) < base.planner.min_obstacle_size:
                    continue  # squeezed between scanned clutter: smaller than the guarantee covers
                if not _clear(box, lo, hi, touchable, self.ends, self.keep, closed):
                    continue
                fat = self.grid.blocked_by(box[0][None] - grow, box[1][None] + grow) & free
                if _connected(fat, self.a, self.g):
                    break
            else:
                raise ScenarioError(
                    f"{base.name}: could not place hidden obstacle {j + 1} of variant {i}"
                    f" in {max_attempts} attempts"
                )
            name = _fresh_name(base.world, added, f"hidden_{j}")
            added.append(Box(name, tuple(box[0]), tuple(box[1])))
            lo, hi = np.vstack([lo, box[0]]), np.vstack([hi, box[1]])
            touchable = np.append(touchable, True)
            free = fat if grow == 0.0 else self.grid.blocked_by(box[0][None], box[1][None]) & free
        return _with_hidden(base, added, i, self.used)


def _keep(body_radius: float, resolution: float, footprint: float | None) -> float:
    """The least distance (m) a hidden obstacle keeps from the start, the goal and the obstacles
    beside it: the body radius + :data:`PLACEMENT_CLEARANCE`, a gap of the body's diameter + two
    map voxels + :data:`GAP_ALLOWANCE`, and a gap that still holds twice the planner's
    ``footprint`` (half-width at a standstill) after losing a map voxel on each side."""
    keep = max(body_radius + PLACEMENT_CLEARANCE, 2 * body_radius + 2 * resolution + GAP_ALLOWANCE)
    if footprint is not None:
        keep = max(keep, 2 * footprint + 2 * resolution)
    return keep


def hidden_obstacle_family(
    kind: Literal["corner", "forest", "auto"] = "auto",
    count: int = 1,
    footprint: float | None = None,
) -> Family:
    """The hidden-obstacle placement of :func:`random_hidden_obstacle_scenarios` as a
    :class:`~secure3d.world.families.Family`: variant ``i`` is drawn from its own generator
    (:func:`~secure3d.world.families.variant_rng`), so it is a pure function of (base, seed, i)
    and campaigns can be sharded. (:func:`random_hidden_obstacle_scenarios` draws every variant
    from one stream instead, so its variants differ from these.)

    ``footprint`` (m, optional): the half-width of the narrowest corridor the planners flown can
    use at a standstill (:func:`secure3d.planning.problem.rest_footprint`: the secure planner's
    reactive set at rest plus its margin). Gaps beside an obstacle then hold twice it after losing
    a map voxel on each side, so that every variant can be passed by a sound planner; narrower
    ones only test that the robot holds. Default: the body radius rule alone."""
    from secure3d.world.families import Family

    if kind not in ("corner", "forest", "auto"):
        raise ScenarioError(f"kind: must be one of corner, forest, auto (got {kind!r})")
    if not is_int_in(count, 1):
        raise ScenarioError(f"count: must be a positive integer (got {count!r})")
    if footprint is not None and not (is_real(footprint, numpy=True) and 0.0 < footprint < 5.0):
        raise ScenarioError(f"footprint: must be a number of metres in (0, 5) (got {footprint!r})")
    return Family(
        name=kind,
        description=f"{count} hidden obstacle(s) placed by rule {kind!r}",
        prepare=functools.partial(_HiddenPlacement.prepare, kind=kind, footprint=footprint),
        variant=lambda prep, base, rng, i: prep.variant(base, rng, i, count),
    )


def _column_box(
    centre: np.ndarray, half: np.ndarray, lo: np.ndarray, hi: np.ndarray, z_range: tuple
) -> tuple[np.ndarray, np.ndarray]:
    """The footprint ``centre +- half`` extruded from the highest obstacle under it that lies
    below ``centre`` (floor, desk) to the lowest one over it that lies above ``centre`` (ceiling),
    within ``z_range``. Obstacles spanning the height of ``centre`` are judged by :func:`_clear`."""
    flo, fhi = centre[:2] - half, centre[:2] + half
    column = np.all(lo[:, :2] < fhi, axis=1) & np.all(hi[:, :2] > flo, axis=1)
    below = column & (hi[:, 2] <= centre[2])
    above = column & (lo[:, 2] >= centre[2])
    z_lo = max(z_range[0], float(hi[below, 2].max(initial=-np.inf)))
    z_hi = min(z_range[1], float(lo[above, 2].min(initial=np.inf)))
    return np.array([*flo, z_lo]), np.array([*fhi, z_hi])


def _clear(
    box: tuple[np.ndarray, np.ndarray],
    lo: np.ndarray,
    hi: np.ndarray,
    touchable: np.ndarray,
    ends: np.ndarray,
    keep: float,
    closed: float = 0.0,
) -> bool:
    """Whether ``box`` keeps ``keep`` from the start/goal ``ends`` (2, 3) and from the obstacles
    beside it (those it neither stands on nor reaches up to). It may also touch a ``touchable``
    one (a named obstacle: a crate against a wall), but leaves no gap narrower than ``keep``.

    Voxels are never touchable: a wall made of many voxel boxes would show a sliver gap to the
    voxels next to the one the box touches. A gap to a voxel narrower than ``closed`` is accepted
    as part of the wall's roughness: a beam wedged between the walls of a scanned corridor touches
    their nearest voxels and leaves gaps of one to a few voxels (0.08-0.48 m on geb079) to the
    voxels set back from them; with ``closed`` 0 no beam, plank or ledge spans a scanned corridor.
    The caller's check on the placement grid still keeps a route for the body."""
    if np.any(box_distance(box[0], box[1], ends, ends) < keep):
        return False
    eps = 1e-9
    beside = (lo[:, 2] < box[1][2] - eps) & (hi[:, 2] > box[0][2] + eps)
    gap = box_distance(box[0], box[1], lo[beside], hi[beside])
    named = touchable[beside]
    shut = np.where(named, gap == 0, gap < closed)
    return bool(np.all((gap >= keep) | shut))


def _fresh_name(world: World, added: list[Box], stem: str) -> str:
    taken = set(world.obstacle_names) | {b.name for b in added}
    name, k = stem, 0
    while name in taken:
        k += 1
        name = f"{stem}_{k}"
    return name


def _with_hidden(base: Scenario, added: list[Box], i: int, kind: str) -> Scenario:
    world = dataclasses.replace(base.world, boxes=(*base.world.boxes, *added))
    server = base.server_map
    if server.from_world:
        hides = tuple(Attack("hide", target=b.name) for b in added)
        server = dataclasses.replace(server, attacks=(*server.attacks, *hides))
    else:  # a file or survey lacks it as it is: say so, so that its detection is reported
        server = dataclasses.replace(server, lacks=(*server.lacks, *(b.name for b in added)))
    names = ", ".join(b.name for b in added)
    note = f"Variant {i}: {kind} hidden obstacle(s) {names} added and hidden from the server map."
    return dataclasses.replace(
        base,
        name=f"{base.name}_hidden_{i:03d}",
        world=world,
        server_map=server,
        description=f"{base.description} {note}".strip(),
    )
