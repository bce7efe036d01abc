"""Exploration when the map denies every route: go and look at the claim that blocks the way.

A server can stop a secure robot without hurting it: claim a wall across the only corridor, out of
the camera's sight, and the belief map shows no route, so the robot holds at the start forever.
The secure planner is right not to fly through space it has not seen; it is wrong to stop looking.

:func:`viewpoint_for_denial` finds what to look at. It asks whether the belief (sensed evidence
over the server's claims) has a route to the goal; if not, it searches the route that crosses as
little claimed-only space as it can (sensed obstacles block; every metre through a claim the
camera has not checked costs :data:`CLAIM_COST` metres), so the route follows real corridors and
crosses the thin claim that closes one rather than a thick block the server told the truth about.
It walks that route to the first point where the body would touch a claimed-only voxel and returns
a point on the route before it, in space the belief holds clear, from which to look. The closed loop plans a certified
plan to that point (the goal replaced, nothing else), flies it, and replans to the real goal from
there; if the claim was a lie, what the camera saw on the way has overridden it.

Nothing here is trusted for safety: the flight to the viewpoint is a secure plan like any other,
certified, re-certified and guarded.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from secure3d.errors import SimulationError
from secure3d.geometry.polytope import min_box_distance
from secure3d.mapping.boxes import merge_cells
from secure3d.planning.guess import (
    NoPathError,
    _clearance_grid,
    _planar,
    graph_path,
    grid_route,
)

__all__ = [
    "CLAIM_COST",
    "LOOK_FROM",
    "goal_unseen",
    "nearer_look",
    "viewpoint_for_denial",
    "viewpoint_for_goal",
]

#: How far before the blocking claim (m, along the route) the robot goes to look at it.
LOOK_FROM = 1.5
#: Cost of a metre through claimed-only space, in metres of free space.
CLAIM_COST = 25.0
#: A blocking point within this distance (m) of the last one looked at is the same claim again.
SAME_CLAIM = 0.5
#: Each look at the same claim again goes this much nearer (a fraction of the last distance), down
#: to MIN_LOOK_FROM (m).
NEARER = 0.5
MIN_LOOK_FROM = 0.4


def _least_claimed_route(
    problem: object, sensed: tuple[np.ndarray, np.ndarray], claimed: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """Polyline (n, 3) from the start to the goal that sensed obstacles do not block and that
    crosses as little claimed-only space as it can (Dijkstra on the planner's guess grid)."""
    r = problem.model.body_radius
    height = _planar(problem)
    grid = dataclasses.replace(problem, boxes_lo=sensed[0], boxes_hi=sensed[1])
    centres, clear, res = _clearance_grid(grid, problem.options.grid_resolution, height)
    claim = dataclasses.replace(problem, boxes_lo=claimed[0], boxes_hi=claimed[1])
    in_claim = (_clearance_grid(claim, res, height)[1] <= r).ravel()
    lo = problem.bounds_lo.copy()
    if height is not None:
        lo[2] = height

    # an edge with an end in claimed space costs CLAIM_COST (>= 1) per metre, else 1
    weight = np.where(in_claim, CLAIM_COST, 1.0)
    try:
        return grid_route(centres, lo, res, clear > r, weight, problem.start_position, problem.goal)
    except NoPathError:
        raise NoPathError("the sensed obstacles alone close every route") from None


def _voxel_boxes(centres: np.ndarray, res: float) -> tuple[np.ndarray, np.ndarray]:
    """Voxels at ``centres`` (n, 3) merged into boxes (lo, hi)."""
    if not len(centres):
        return np.zeros((0, 3)), np.zeros((0, 3))
    lo, hi = merge_cells(np.floor(centres / res).astype(np.int64))
    return lo * res, (hi + 1) * res


def _dense(path: np.ndarray, step: float) -> np.ndarray:
    """The polyline ``path`` (n, 3) resampled every ``step`` metres or less."""
    out = [path[:1]]
    for a, b in zip(path[:-1], path[1:], strict=True):
        k = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        out.append(a + np.linspace(0.0, 1.0, k + 1)[1:, None] * (b - a))
    return np.vstack(out)


def viewpoint_for_denial(
    problem: object, belief: object, look_from: float = LOOK_FROM
) -> tuple[np.ndarray, np.ndarray] | None:
    """Where to go to look at the claim that closes every route, or None.

    Parameters
    ----------
    problem : the :class:`~secure3d.planning.problem.PlanningProblem` of a replan from the robot's
        state (its boxes are the belief's known obstacles, claims included).
    belief : the robot's :class:`~secure3d.mapping.occupancy.OccupancyMap`.
    look_from : distance along the route before the blocking claim to look from (m).

    Returns
    -------
    (viewpoint (3,), blocking point (3,)), or None when the belief has a route (no denial), when
    the sensed obstacles alone close the way too (nothing to look at), or when no point before
    the claim is clear.
    """
    found = _blocked_route(problem, belief)
    return None if found is None else _view_of(problem, *found, look_from)


def _blocked_route(problem: object, belief: object) -> tuple[np.ndarray, int, float] | None:
    """The least-claimed route (n, 3), the index of its first point whose body touches a claim,
    and the map resolution; None when there is nothing to look at (see
    :func:`viewpoint_for_denial`)."""
    from secure3d.mapping.occupancy import Trust

    try:
        graph_path(problem)
        return None  # the belief has a route: not a denial
    except NoPathError:
        pass
    occ, trust = belief.known_obstacles()
    res = belief.resolution
    claimed = occ[trust == Trust.CLAIMED_OCCUPIED]
    if not len(claimed):
        return None
    sensed = _voxel_boxes(occ[trust == Trust.SENSED_OCCUPIED], res)
    claim_lo, claim_hi = _voxel_boxes(claimed, res)
    try:
        route = _dense(_least_claimed_route(problem, sensed, (claim_lo, claim_hi)), 0.5 * res)
    except NoPathError:
        return None  # what the camera saw closes the way by itself
    touching = np.flatnonzero(
        min_box_distance(route, claim_lo, claim_hi) <= problem.model.body_radius
    )
    return None if not len(touching) else (route, int(touching[0]), res)


def _view_of(
    problem: object,
    route: np.ndarray,
    block: int,
    res: float,
    look_from: float,
    toward: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """(viewpoint, blocking point) ``look_from`` before ``route[block]``, or None. The viewpoint
    keeps the body a voxel clear of every known obstacle, and the reactive set at rest there its
    margin (:func:`rest_set_clear`): a plan must end at it. ``toward``: a nearer look at a claim
    seen before (see :func:`_look_from`)."""
    r = problem.model.body_radius
    view = _look_from(route, block, problem, look_from, 3 * res, r + res, toward)
    return None if view is None else (view, route[block].copy())


def rest_set_clear(problem: object, at: np.ndarray) -> bool:
    """Whether the planner's reactive set at rest at ``at`` (3,) keeps its margin from every known
    obstacle box of ``problem`` (exact ellipsoid-to-box distances): a secure plan can end at rest
    there only then. (A quadrotor's denial viewpoint 0.306 m from a wall, the body radius plus a
    voxel, left its 0.295 m set 0.011 m from the wall against a 0.02 m margin: every plan to it ran
    into the iteration limit and the robot held.)"""
    from secure3d.geometry.polytope import box_pair_distances

    at = np.asarray(at, dtype=float)
    if at.shape != (3,) or not np.all(np.isfinite(at)):
        raise SimulationError(f"rest_set_clear: at must be 3 finite numbers, got {at!r}")
    c, M = problem.family.ellipsoid(problem.model.rest_state(at, 0.0))
    c, M = np.asarray(c, dtype=float).ravel(), np.asarray(M, dtype=float).reshape(3, 3)
    margin = float(problem.options.margin)
    reach = np.linalg.norm(M, axis=1) + margin  # E's bounding box, grown by the margin
    lo, hi = problem.boxes_lo, problem.boxes_hi
    near = np.flatnonzero(np.all((lo <= c + reach) & (hi >= c - reach), axis=1))
    if not len(near):
        return True
    n = len(near)
    cs, Ms = np.repeat(c[None], n, axis=0), np.repeat(M[None], n, axis=0)
    dist = box_pair_distances(cs, cs, Ms, lo[near], hi[near], np.zeros(n, dtype=bool))
    return bool(np.all(dist >= margin))


def nearer_look(
    problem: object, belief: object, last_block: np.ndarray | None, last_look_from: float
) -> tuple[tuple[np.ndarray, np.ndarray] | None, float]:
    """:func:`viewpoint_for_denial`, nearer the claim when it is the one looked at last time.

    A look that did not clear a claim (the same blocking point comes back) usually saw nothing
    behind it: with a depth camera a ray that ends past its range clears nothing, and a claim in
    front of open space is refuted only by rays that hit a surface behind it. From nearer, that
    surface is nearer too (a campaign's denial variant looked three times from 1.5 m before a
    phantom slab, with the wall behind it 5.9 m from the viewpoint against a 6 m range, and
    held). When no point lies
    LOOK_FROM before the claim along the route (the robot is nearer already, after a look that a
    corner occluded), nearer ones are tried too. Returns the viewpoint and blocking point (or
    None) and the distance it looks from."""
    if not (np.isfinite(last_look_from) and last_look_from > 0):
        raise SimulationError(f"nearer_look: last_look_from must be > 0 m, got {last_look_from!r}")
    found = _blocked_route(problem, belief)  # the route does not depend on the distance
    if found is None:
        return None, LOOK_FROM
    first = _view_of(problem, *found, LOOK_FROM)
    look = LOOK_FROM
    if first is not None:
        if last_block is None or np.linalg.norm(first[1] - last_block) > SAME_CLAIM:
            return first, LOOK_FROM
        look = last_look_from  # the same claim again: nearer than last time
    # no point LOOK_FROM before the claim (the robot is nearer already), or the same claim again
    from secure3d.mapping.occupancy import Trust

    seen_free = belief.trust(found[0]) == Trust.SENSED_FREE  # the route points the camera saw free
    while look > MIN_LOOK_FROM:
        look = max(MIN_LOOK_FROM, NEARER * look)
        nearer = _view_of(problem, *found, look, seen_free)
        if nearer is not None:
            return nearer, look
    return first, LOOK_FROM


def _look_from(
    route: np.ndarray,
    block: int,
    problem: object,
    near: float,
    start: float,
    clearance: float,
    toward: np.ndarray | None = None,
) -> np.ndarray | None:
    """The point of ``route`` (n, 3) to look at ``route[block]`` from: at least ``near`` metres
    before it along the route and ``start`` metres after the route's start, with the body
    ``clearance`` from every known obstacle and the reactive set at rest its margin
    (:func:`rest_set_clear`); among those, the first (nearest the robot) whose sight line to the
    blocking point is clear and shorter than 0.8 of the observed range, else the one nearest the
    claim. With ``toward`` (n,) bool (a nearer look at a claim seen before: the route points the
    camera has seen free), those of the points in sight nearest the claim come first, so that the
    robot goes nearer: it already stands in sight of the claim, and the point in sight nearest it
    was where it stood (a diff drive looked five times from points 0.17 m apart, 1.2-1.6 m from a
    claim it refuted a few voxels at a time, and held). The points only the server calls free come
    after them: the camera has not seen them, and the server may lie. The set at rest is judged
    only on the points in turn until one passes."""
    from secure3d.geometry.polytope import segments_blocked

    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route, axis=0), axis=1))])
    before = np.flatnonzero((arc <= arc[block] - near) & (arc >= start))
    before = before[min_box_distance(route[before], problem.boxes_lo, problem.boxes_hi) > clearance]
    if not len(before):
        return None
    target = np.repeat(route[block][None], len(before), axis=0)
    in_reach = np.linalg.norm(target - route[before], axis=1) <= 0.8 * problem.frustum.far
    sight = in_reach & ~segments_blocked(route[before], target, problem.boxes_lo, problem.boxes_hi)
    seen = before[sight]
    if toward is not None:
        seen = np.concatenate([seen[toward[seen]][::-1], seen[~toward[seen]]])
    order = np.concatenate([seen, before[::-1]])  # in sight first, then nearest the claim
    pick = next((i for i in order if rest_set_clear(problem, route[i])), None)
    return None if pick is None else route[pick].copy()


#: Distances (m, horizontal) from the goal and bearings (rad, about the line from the goal to the
#: robot) :func:`viewpoint_for_goal` tries, nearest the robot first.
GOAL_VIEW_DISTANCES = np.arange(0.5, 4.01, 0.25)
GOAL_VIEW_BEARINGS = np.radians([0.0, 30.0, -30.0, 60.0, -60.0])


def _point(a: object, what: str) -> np.ndarray:
    """``a`` as 3 finite numbers, or a one-line error naming ``what``."""
    p = np.asarray(a, dtype=float).ravel()
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise SimulationError(f"{what} must be 3 finite numbers, got {a!r}")
    return p


def goal_unseen(problem: object, belief: object, goal: np.ndarray) -> bool:
    """Whether some voxel of the bounding box of the planner's reactive set at rest at ``goal``
    (3,) is one the camera has never sensed (unknown, or known only from the server's claim): no
    plan can end there until a view covers it."""
    from secure3d.mapping.occupancy import Trust
    from secure3d.simulation.retreat import voxel_cells

    goal = _point(goal, "goal_unseen: goal")
    c, M = problem.family.ellipsoid(problem.model.rest_state(goal, 0.0))
    c, M = np.asarray(c, dtype=float).ravel(), np.asarray(M, dtype=float).reshape(3, 3)
    reach = np.linalg.norm(M, axis=1)
    res = belief.resolution
    cells = voxel_cells(c - reach, c + reach, res)
    trust = belief.trust((cells + 0.5) * res)
    return bool(np.any(~np.isin(trust, [Trust.SENSED_FREE, Trust.SENSED_OCCUPIED])))


def viewpoint_for_goal(
    problem: object, belief: object, position: np.ndarray, goal: np.ndarray
) -> np.ndarray | None:
    """Where to stand, at rest facing the goal, for the camera to hold the planner's reactive set
    at rest at ``goal`` (3,) in view (:func:`_sees`), or None: a planar vehicle, a robot at
    ``position`` (3,) that holds it in view already, or no such point.

    A robot that stopped near the goal but above or beside it, with a level camera whose vertical
    view is narrow, cannot plan to the goal: a plan that ends there needs a view of the space round
    it, from one of its own earlier poses or the start region, and a map that sensed that space
    from afar is not enough (OctoMap's scan.dat as the world, dead ends 0.7-1.1 m from the goal
    with the robot 0.45-0.65 m above it: every plan went 10-15 m round or ran out of budget).
    Standing farther back, the same view covers more. Candidates lie at the robot's height (a
    level camera cannot look where the robot would descend), then the goal's,
    ``GOAL_VIEW_DISTANCES`` from the goal along ``GOAL_VIEW_BEARINGS`` about the line to the
    robot, nearest the robot first. A point passes when it is in the map, the body a voxel clear
    of every known box, the goal set in view from it, the set at rest there its margin from every
    known box (:func:`rest_set_clear`) and in space the camera has sensed (a plan ends there), and
    the straight way there from the robot seen free (:func:`_seen_between`). The flight there is a
    certified plan like any other."""
    g = _point(goal, "viewpoint_for_goal: goal")
    p = _point(position, "viewpoint_for_goal: position")
    model = problem.model
    c, M = problem.family.ellipsoid(model.rest_state(g, 0.0))
    c, M = np.asarray(c, dtype=float).ravel(), np.asarray(M, dtype=float).reshape(3, 3)
    if model.planar or _sees(problem, p, (c, M)):
        return None
    back = p[:2] - g[:2]
    base = float(np.arctan2(back[1], back[0])) if np.linalg.norm(back) > 1e-9 else 0.0
    cands = [
        np.array([g[0] + d * np.cos(base + a), g[1] + d * np.sin(base + a), z])
        for z in dict.fromkeys([float(p[2]), float(g[2])])
        for a in GOAL_VIEW_BEARINGS
        for d in GOAL_VIEW_DISTANCES
    ]
    # level with the robot first, nearest it
    cands.sort(key=lambda v: (abs(float(v[2] - p[2])) > 1e-9, float(np.linalg.norm(v - p))))
    r, res = model.body_radius, belief.resolution
    lo_b, hi_b = problem.bounds_lo + r + res, problem.bounds_hi - r - res
    for v in cands:
        if np.any(v < lo_b) or np.any(v > hi_b):
            continue
        if min_box_distance(v[None], problem.boxes_lo, problem.boxes_hi)[0] <= r + res:
            continue
        if (
            _sees(problem, v, (c, M))
            and rest_set_clear(problem, v)
            and not goal_unseen(problem, belief, v)
            and _seen_between(belief, p, v, r)
        ):
            return v
    return None


def _sees(problem: object, at: np.ndarray, ellipsoid: tuple[np.ndarray, np.ndarray]) -> bool:
    """Whether the camera of the robot at rest at ``at`` (3,), facing the ellipsoid (c (3,), M
    (3, 3)), holds all of it in its field of view (every face, with the planner's margin) with a
    clear sight line from the camera to its centre."""
    from secure3d.geometry.frustum import frustum_halfspaces
    from secure3d.geometry.polytope import segments_blocked

    model, (c, M) = problem.model, ellipsoid
    yaw = float(np.arctan2(c[1] - at[1], c[0] - at[0]))
    R, o = model.camera_pose(model.rest_state(at, yaw))
    o = np.asarray(o, dtype=float).ravel()
    A, b = frustum_halfspaces(np.asarray(R, dtype=float), o, problem.frustum)
    A, b = np.asarray(A, dtype=float), np.asarray(b, dtype=float).ravel()
    if np.any(b - A @ c - np.linalg.norm(A @ M, axis=1) < problem.options.margin):
        return False
    return not segments_blocked(o[None], c[None], problem.boxes_lo, problem.boxes_hi)[0]


def _seen_between(belief: object, a: np.ndarray, b: np.ndarray, radius: float) -> bool:
    """Whether every voxel within ``radius`` (a cube, conservatively) of the segment from ``a`` to
    ``b`` (3,) is one the camera has seen free."""
    from secure3d.mapping.occupancy import Trust

    res = belief.resolution
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / (0.5 * res))) + 1)
    pts = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
    k = int(np.ceil(radius / res))
    offsets = np.stack(np.meshgrid(*[np.arange(-k, k + 1)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = np.unique(
        (np.floor(pts / res).astype(np.int64)[:, None, :] + offsets).reshape(-1, 3), axis=0
    )
    return bool(np.all(belief.trust((cells + 0.5) * res) == Trust.SENSED_FREE))
