"""Initial guesses: a graph search on a voxel grid of the belief, then a feasible time scaling.

The paper notes that poor (infeasible) guesses stop convergence; a collision-free path with clearance,
flown at a moderate speed with a trapezoidal speed profile, is a good start for both planners.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.sparse import csr_matrix

from secure3d.errors import PlanningError
from secure3d.mapping.sensor_model import Trust
from secure3d.planning.problem import Planner, PlanningProblem, Solver
from secure3d.planning.trajectory import remainder_keeping_nodes, resample

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.result import PlanResult

#: Largest number of grid cells the graph search uses; the grid is coarsened to stay below it.
MAX_GRID_CELLS = 120_000
#: Slowest speed of a guess's time scaling (m/s): where no speed is visible, the guess crawls.
CRAWL_SPEED = 0.05
#: A candidate of :mod:`secure3d.planning.visible_paths` replaces a crawling guess when its time
#: scaling is this much faster.
CANDIDATE_GAIN = 0.8
#: The graph search's cost per metre through a cell no source describes, relative to described
#: space (:func:`unknown_cost`).
UNKNOWN_COST = 1.5


@dataclass(frozen=True)
class Guess:
    """A time-parametrised initial trajectory: node times (K,), states (K, nx), controls (K, nu)."""

    times: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    path: np.ndarray

    @property
    def final_time(self) -> float:
        return float(self.times[-1])


class NoPathError(RuntimeError):
    """The graph search found no collision-free path (reported as INFEASIBLE by the planner)."""


def _planar(problem: PlanningProblem) -> float | None:
    """Fixed height of a planar model, or None for 3D models."""
    if problem.model.planar:
        return float(problem.start_position[2])
    return None


def _clearance_grid(
    problem: PlanningProblem, resolution: float, height: float | None
) -> tuple[np.ndarray, np.ndarray, float]:
    """Distance from each grid cell centre to the nearest known obstacle or the bounds (m)."""
    lo, hi = problem.bounds_lo.copy(), problem.bounds_hi.copy()
    if height is not None:
        lo[2] = hi[2] = height
    ext = np.maximum(hi - lo, 1e-9)
    dims3 = np.where(ext > 1e-6, ext, 0.0)
    res = resolution
    while True:
        shape = np.maximum(1, np.floor(dims3 / res).astype(int) + 1)
        if int(np.prod(shape)) <= MAX_GRID_CELLS:
            break
        res *= 1.25
    axes = [
        np.linspace(lo[d], hi[d], shape[d]) if shape[d] > 1 else np.array([lo[d]]) for d in range(3)
    ]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    clearance = np.full(len(centres), np.inf)
    for d in range(3):
        if shape[d] > 1:
            clearance = np.minimum(clearance, centres[:, d] - problem.bounds_lo[d])
            clearance = np.minimum(clearance, problem.bounds_hi[d] - centres[:, d])
    if len(problem.boxes_lo):
        # the distance to the bounds caps each search: min(bounds, boxes), exactly
        clearance = problem.box_index.min_distance(centres, clearance)
    return centres, clearance.reshape(shape), res


def graph_path(problem: PlanningProblem, clearance_pad: float = 0.15) -> np.ndarray:
    """Collision-free polyline from the start to the goal; the grid is refined (down to 1/8 of the
    option ``grid_resolution``) until a path through narrow passages appears."""
    resolution = problem.options.grid_resolution
    for _ in range(4):
        try:
            return _graph_path(problem, resolution, clearance_pad)
        except NoPathError:
            resolution /= 2
    return _graph_path(problem, resolution, clearance_pad)


def _graph_path(problem: PlanningProblem, resolution: float, clearance_pad: float) -> np.ndarray:
    """Collision-free polyline (n, 3) from the start to the goal with clearance, by Dijkstra.

    Cells closer than body radius + margin to a known obstacle are blocked; edge costs grow near
    obstacles (keeping to the middle of corridors, which the secure planner likes: the paper's
    secure path "gives wide berth to the known obstacle").
    """
    height = _planar(problem)
    centres, clearance, res = _clearance_grid(problem, resolution, height)
    r = problem.model.body_radius
    free = clearance > r
    start, goal = problem.start_position, problem.goal
    lo = problem.bounds_lo.copy()
    if height is not None:
        lo[2] = height

    weight = clearance_weight(clearance.ravel(), r, clearance_pad) * unknown_cost(problem, centres)
    pts = grid_route(centres, lo, res, free, weight, start, goal)
    return _shortcut(pts, lambda p: _clear_at(p, clearance, lo, res) > r + 0.5 * clearance_pad)


def unknown_cost(problem: PlanningProblem, centres: np.ndarray) -> np.ndarray | float:
    """Cost factor per grid cell, (n,) for ``centres`` (n, 3): :data:`UNKNOWN_COST` where no source
    describes the cell's voxel (no claim and no sensor evidence), else 1; 1 with no map, or a
    server map that claims no free space (a list of obstacles describes only those).

    A server map made of scans (a lidar survey, a real scan with gaps) leaves the inside of walls
    unknown, and a guess through it costs solves and replans until the camera finds the wall;
    space some source called free is where a route most likely is. Unknown space stays passable:
    only the certificate decides what the robot may enter."""
    if np.ndim(centres) != 2 or np.shape(centres)[1] != 3:
        raise PlanningError(f"unknown_cost: centres must be (n, 3), got shape {np.shape(centres)}")
    occupancy = problem.occupancy
    if occupancy is None or not len(centres) or not occupancy.claims_free:
        return 1.0
    unknown = occupancy.trust(centres) == Trust.UNKNOWN
    return np.where(unknown, UNKNOWN_COST, 1.0)


def clearance_weight(clearance: np.ndarray, radius: float, pad: float) -> np.ndarray:
    """Cost per metre (>= 1) of a grid edge whose nearer end has ``clearance`` (m), for a body of
    ``radius``: it grows as the clearance falls to the body within ``pad``. It never rises with the
    clearance, in floating point too (every operation is monotone), so an edge's weight, that of
    its ends' smaller clearance, is the larger of its ends' weights: one per cell, not per edge."""
    if not (np.isfinite(radius) and radius >= 0 and np.isfinite(pad) and pad >= 0):
        raise PlanningError(
            f"clearance_weight: radius and pad must be >= 0 (m), got {radius!r}, {pad!r}"
        )
    return 1.0 + 1.0 / (0.25 + np.maximum(clearance - radius, 0.0) / max(pad, 1e-3))


def grid_route(
    centres: np.ndarray,
    lo: np.ndarray,
    res: float,
    free: np.ndarray,
    weight: np.ndarray,
    start: np.ndarray,
    goal: np.ndarray,
) -> np.ndarray:
    """Cheapest 26-connected route over a grid, by Dijkstra: the cell centres (n, 3) from the
    start's cell to the goal's, with the exact start and goal as its ends.

    Parameters
    ----------
    centres : (N, 3) cell centres of a grid of shape ``free.shape`` whose cell (0, 0, 0) is at
        ``lo``, spaced ``res``.
    free : (a, b, c) bool, the cells a route may use (the start's and goal's cells always may).
    weight : (N,) float > 0, cost per metre of each cell: an edge costs its length times the
        larger of its ends' weights (:func:`~secure3d.planning._grid_kernel.grid_search`: scipy's
        ``dijkstra`` route on the graph of :func:`grid_graph`, ties included, without building it).

    Raises
    ------
    NoPathError
        No route of free cells joins them.
    """
    from secure3d.planning._grid_kernel import grid_search

    shape = free.shape
    weight = np.ascontiguousarray(np.broadcast_to(np.asarray(weight, dtype=float), free.size))
    if not np.all(weight > 0):  # NaN too
        raise PlanningError("grid_route: every cell weight must be a number > 0")

    def cell_of(p: np.ndarray) -> int:
        idx = np.clip(np.round((p - lo) / res).astype(int), 0, np.array(shape) - 1)
        return int(np.ravel_multi_index(tuple(idx), shape))

    flat_free = free.ravel().copy()
    s_cell, g_cell = cell_of(start), cell_of(goal)
    if s_cell == g_cell:
        # One cell holds both: the route is the segment between them. (Its one cell, with the
        # start then overwritten by the goal, made a path of no length and a guess of NaN
        # tangents: a denial viewpoint 0.17 m away crashed a diff-drive flight.)
        return np.array([start, goal], dtype=float)
    # The start/goal cells may be blocked by discretisation: free them.
    for c in (s_cell, g_cell):
        flat_free[c] = True
    dims = np.asarray(shape, np.int64)
    cells, _ = grid_search(
        flat_free, dims, GRID_OFFSETS, res * _OFFSET_LENGTHS, weight, s_cell, g_cell
    )
    if not len(cells):
        raise NoPathError(
            f"no collision-free path from {np.round(start, 2)} to {np.round(goal, 2)} in the belief map"
        )
    pts = centres[cells]
    pts[0], pts[-1] = start, goal
    return pts


#: The 26 neighbour offsets of a grid cell, in increasing order of their flat step, and their
#: lengths in cells.
GRID_OFFSETS = np.array([o for o in np.ndindex(3, 3, 3) if o != (1, 1, 1)], np.int64) - 1
_OFFSET_LENGTHS = np.sqrt((GRID_OFFSETS**2).sum(axis=1).astype(float))


def grid_graph(
    free: np.ndarray,
    shape: tuple[int, int, int],
    res: float,
    edge_cost: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
) -> csr_matrix:
    """The 26-connected graph of a grid's free cells as a canonical CSR matrix (rows sorted,
    no duplicates): ``free`` (N,) bool flat cells of ``shape``, spaced ``res``; edge weights
    ``edge_cost(src, dst, length)`` with arrays (E,). Its edges are listed by a compiled kernel
    (:func:`secure3d.planning._grid_kernel.grid_edges`)."""
    from secure3d.planning._grid_kernel import grid_edges

    dims = np.asarray(shape, np.int64)
    free = np.asarray(free)
    if dims.shape != (3,) or np.any(dims < 1):
        raise PlanningError(f"grid_graph: shape must be 3 positive cell counts, got {shape!r}")
    if free.dtype != bool or free.shape != (int(np.prod(dims)),):
        raise PlanningError(
            f"grid_graph: free must be {int(np.prod(dims))} flat bools for shape {tuple(dims)},"
            f" got {free.dtype} array of shape {free.shape}"
        )
    if free.size * len(GRID_OFFSETS) >= 2**31:  # int32 edge indices (MAX_GRID_CELLS keeps below)
        raise PlanningError(f"grid of {free.size} cells: too large for a graph search")
    indptr, src, dst, kind = grid_edges(free, dims, GRID_OFFSETS)
    lengths = res * _OFFSET_LENGTHS
    graph = csr_matrix((edge_cost(src, dst, lengths[kind]), dst, indptr), shape=(free.size,) * 2)
    graph.sort_indices()  # already sorted when every axis has 3 or more cells
    return graph


def _clear_at(points: np.ndarray, clearance: np.ndarray, lo: np.ndarray, res: float) -> np.ndarray:
    """Grid clearance looked up at points (nearest cell; trilinear would be overkill here)."""
    idx = np.clip(np.round((points - lo) / res).astype(int), 0, np.array(clearance.shape) - 1)
    return clearance[idx[:, 0], idx[:, 1], idx[:, 2]]


def _shortcut(points: np.ndarray, is_free: object) -> np.ndarray:
    """Greedy string pulling: keep a vertex only when the straight shortcut past it is not free."""
    out = [points[0]]
    i = 0
    n = len(points)
    while i < n - 1:
        j = n - 1
        while j > i + 1:
            seg = np.linspace(
                points[i], points[j], max(2, int(np.linalg.norm(points[j] - points[i]) / 0.05))
            )
            if np.all(is_free(seg[1:-1])) if len(seg) > 2 else True:
                break
            j -= 1
        out.append(points[j])
        i = j
    return np.array(out)


def _densify(path: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` metres along a polyline and their arc lengths."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    n = max(2, int(np.ceil(arc[-1] / step)) + 1)
    s = np.linspace(0.0, arc[-1], n)
    pts = np.stack([np.interp(s, arc, path[:, d]) for d in range(3)], axis=1)
    return pts, s


def look_ahead_yaw(points: np.ndarray, arc: np.ndarray, distance: float, yaw0: float) -> np.ndarray:
    """Heading toward the path point ``distance`` metres ahead (unwrapped, starting near ``yaw0``):
    the camera looks into a corner before the body turns."""
    ahead = np.stack([np.interp(arc + distance, arc, points[:, d]) for d in range(3)], axis=1)
    d = (ahead - points)[:, :2]
    tangent = np.gradient(points[:, :2], axis=0)
    # near the end of the path nothing lies ahead any more: keep looking along the path
    short = np.linalg.norm(d, axis=1) < 0.5 * max(distance, 1e-6)
    d[short] = tangent[short]
    yaw = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    return yaw + np.round((yaw0 - yaw[0]) / (2 * np.pi)) * 2 * np.pi


def secure_speed_caps(
    problem: PlanningProblem,
    points: np.ndarray,
    tangents: np.ndarray,
    yaws: np.ndarray,
    v_cap: float,
    levels: int = 12,
) -> np.ndarray:
    """Largest speed at each path point whose reactive set is already observed: inside the start
    ball, or inside the frustum of an earlier path point with a clear line of sight (the paper's
    eq. FullConstraint along a geometric path, before any optimisation)."""
    from secure3d.planning.lookback import (
        frustum_margins,
        node_geometry,
        sight_tips,
        start_margins,
    )

    model, o = problem.model, problem.options
    n = len(points)
    speeds = np.linspace(0.0, v_cap, levels)
    X = model.initial_states(
        np.repeat(points, levels, axis=0),
        (speeds[None, :, None] * tangents[:, None, :]).reshape(-1, 3),
        np.repeat(yaws, levels),
    )
    cams = model.initial_states(points, 0.0 * tangents, yaws)
    geo_e = node_geometry(problem, X)
    geo_c = node_geometry(problem, cams)
    geo = {"C": geo_e["C"], "M": geo_e["M"], "R": geo_c["R"], "o": geo_c["o"]}
    owner = np.repeat(np.arange(n), levels)
    # (n*levels, n), the earlier cameras only (the later ones -inf: never seen)
    seen = frustum_margins(problem, geo, owner) >= o.margin
    visible = seen.any(axis=1)
    if o.occlusion and len(problem.boxes_lo):
        # a clear sight from one of the cameras that frame it: the nearest tried first
        tips = sight_tips(geo["C"], geo["M"])
        indptr = np.concatenate([[0], np.cumsum(seen.sum(axis=1))])
        cols = np.nonzero(seen[:, ::-1])[1]
        visible = problem.box_index.fans_clear(geo["o"], tips, indptr, n - 1 - cols)
    ok = visible | (start_margins(problem, geo) >= o.margin)
    ok = ok.reshape(n, levels)
    ok[:, 0] = True  # at rest the robot can always wait (its reactive set is its own body)
    # the largest level such that every slower one is feasible too
    first_bad = np.where(ok.all(axis=1), levels, np.argmin(ok, axis=1))
    return speeds[np.maximum(first_bad - 1, 0)]


#: A turn-in-place vehicle whose path starts more than this far (rad) from its heading first brakes
#: to rest along its heading and turns on the spot in the guess (see :func:`stop_and_turn`).
TURN_ROUND_ANGLE = np.pi / 2


def stop_and_turn(
    p0: np.ndarray, v0: float, yaw0: float, yaw1: float, a_max: float, yaw_rate: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A turn-in-place vehicle's way round: brake at ``a_max`` from speed ``v0`` (m/s, along the
    heading ``yaw0``) at ``p0`` (3,) to rest, then turn on the spot to ``yaw1`` at 70 % of
    ``yaw_rate``. Returns samples (times (n,), positions (n, 3), velocities (n, 3), yaws (n,))
    from t = 0; the last one at rest, facing ``yaw1``.

    Without it a guess for a robot facing a dead end flipped its heading by pi in one node while
    still driving at 1.3 m/s, and IPOPT ran out of iterations (issue 16, diff drive with dead
    ends)."""
    for name, value in (("a_max", a_max), ("yaw_rate", yaw_rate)):
        if not (np.isfinite(value) and value > 0):
            raise PlanningError(f"stop_and_turn: {name} must be > 0, got {value!r}")
    p0 = np.asarray(p0, dtype=float)
    if p0.shape != (3,) or not np.all(np.isfinite([*p0, v0, yaw0, yaw1])):
        raise PlanningError(
            f"stop_and_turn: p0 must be 3 finite numbers and v0, yaw0, yaw1 finite, got"
            f" p0 shape {p0.shape}, v0 {v0!r}, yaw0 {yaw0!r}, yaw1 {yaw1!r}"
        )
    heading = np.array([np.cos(yaw0), np.sin(yaw0), 0.0])
    v0 = max(float(v0), 0.0)
    t_b = v0 / a_max
    tb = np.linspace(0.0, t_b, 8)
    along = v0 * tb - 0.5 * a_max * tb**2
    turn = abs(yaw1 - yaw0) / (0.7 * yaw_rate)
    tt = t_b + np.linspace(0.0, turn, 9)[1:]
    times = np.concatenate([tb, tt])
    pos = np.concatenate(
        [p0 + along[:, None] * heading, np.repeat([p0 + along[-1] * heading], 8, 0)]
    )
    vel = np.concatenate([(v0 - a_max * tb)[:, None] * heading, np.zeros((8, 3))])
    yaws = np.concatenate([np.full(8, yaw0), np.linspace(yaw0, yaw1, 9)[1:]])
    return times, pos, vel, yaws


def _turn_round(
    problem: PlanningProblem, pts: np.ndarray, arc: np.ndarray, a_max: float, yaw_rate: float
):
    """The stop-and-turn samples for a model that heads along its path (a turn-in-place vehicle)
    whose path ``pts`` leaves against its heading (see :data:`TURN_ROUND_ANGLE`), or None."""
    model = problem.model
    if not model.heading_follows_path or arc[-1] <= 0.0:
        return None
    yaw0 = float(model.yaw(problem.x0))
    d = pts[min(np.searchsorted(arc, 0.3), len(pts) - 1)] - pts[0]
    yaw1 = float(np.arctan2(d[1], d[0]))
    yaw1 += np.round((yaw0 - yaw1) / (2 * np.pi)) * 2 * np.pi
    if abs(yaw1 - yaw0) <= TURN_ROUND_ANGLE:
        return None
    v0 = float(np.dot(model.velocity(problem.x0)[:2], [np.cos(yaw0), np.sin(yaw0)]))
    p0 = np.asarray(model.position(problem.x0), dtype=float).ravel()
    return stop_and_turn(p0, v0, yaw0, yaw1, a_max, yaw_rate)


def profile_guess(
    problem: PlanningProblem, path: np.ndarray, speed_fraction: float, secure: bool
) -> Guess:
    """Time-parametrise ``path``: speed caps (limit, yaw rate, and for the secure planner the
    visibility of the reactive set), then forward/backward acceleration passes; K nodes equally
    spaced in time. A turn-in-place vehicle whose path leaves against its heading first stops and
    turns round (:func:`stop_and_turn`)."""
    model = problem.model
    K = problem.options.nodes
    pts, arc = _densify(path, 0.2)
    v_max, a_max, yaw_rate = model.speed_limit, 0.6 * model.nominal_accel, model.yaw_rate_limit
    yaw0 = float(model.yaw(problem.x0))
    v_start = min(float(np.linalg.norm(model.velocity(problem.x0))), v_max)
    prefix = _turn_round(problem, pts, arc, a_max, yaw_rate)
    if prefix is not None:
        # the path then starts where the robot stopped (back over its braking distance)
        pts, arc = _densify(np.vstack([prefix[1][-1], path]), 0.2)
        yaw0, v_start = float(prefix[3][-1]), 0.0
    t_arc, v, yaw, tang = _speed_profile(problem, pts, arc, speed_fraction, secure, yaw0, v_start)
    if prefix is None:
        times = np.linspace(0.0, t_arc[-1], K)
        s_k = np.interp(times, t_arc, arc)
        pos = np.stack([np.interp(s_k, arc, pts[:, d]) for d in range(3)], axis=1)
        vel = np.stack([np.interp(s_k, arc, v * tang[:, d]) for d in range(3)], axis=1)
        yaw_k = np.interp(s_k, arc, yaw)
    else:  # stop, turn on the spot (no arc length), then the path: interpolate in time
        t0 = prefix[0][-1]
        t_all = np.concatenate([prefix[0], t0 + t_arc[1:]])
        p_all = np.concatenate([prefix[1], pts[1:]])
        v_all = np.concatenate([prefix[2], v[1:, None] * tang[1:]])
        y_all = np.concatenate([prefix[3], yaw[1:]])
        times = np.linspace(0.0, t_all[-1], K)
        pos = np.stack([np.interp(times, t_all, p_all[:, d]) for d in range(3)], axis=1)
        vel = np.stack([np.interp(times, t_all, v_all[:, d]) for d in range(3)], axis=1)
        yaw_k = np.interp(times, t_all, y_all)
    states, controls = model.guess_rates(model.initial_states(pos, vel, yaw_k), times)
    states[0] = problem.x0
    return Guess(times=times, states=states, controls=controls, path=path)


def _speed_profile(
    problem: PlanningProblem,
    pts: np.ndarray,
    arc: np.ndarray,
    speed_fraction: float,
    secure: bool,
    yaw0: float,
    v_start: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Speeds along the densified path ``pts`` (n, 3) at arc lengths ``arc`` (n,): caps (limit,
    yaw rate, and for the secure planner the visibility of the reactive set), then forward and
    backward acceleration passes from ``v_start`` to rest. Returns (times (n,), speeds (n,),
    yaws (n,), unit tangents (n, 3))."""
    model = problem.model
    tang = np.gradient(pts, arc, axis=0)
    tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-9)
    v_max = model.speed_limit
    a_max = 0.6 * model.nominal_accel
    yaw_rate = model.yaw_rate_limit
    # A robot that heads where it goes faces the path's tangent; the others look 1.5 m ahead.
    yaw = look_ahead_yaw(pts, arc, 0.0 if model.heading_follows_path else 1.5, yaw0)
    cap = np.full(len(pts), speed_fraction * v_max)
    dyaw = np.abs(np.gradient(yaw, arc))
    cap = np.minimum(cap, 0.7 * yaw_rate / np.maximum(dyaw, 1e-6))
    if secure:
        cap = np.minimum(cap, secure_speed_caps(problem, pts, tang, yaw, speed_fraction * v_max))
    cap = np.maximum(cap, CRAWL_SPEED)
    v = cap.copy()
    ds = np.diff(arc)
    v[0] = v_start
    for i in range(1, len(v)):
        v[i] = min(v[i], np.sqrt(v[i - 1] ** 2 + 2 * a_max * ds[i - 1]))
    v[-1] = 0.0
    for i in range(len(v) - 2, 0, -1):
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * a_max * ds[i]))
    dt = 2 * ds / np.maximum(v[:-1] + v[1:], 1e-3)
    return np.concatenate([[0.0], np.cumsum(dt)]), v, yaw, tang


def centre_path(
    problem: PlanningProblem, path: np.ndarray, pad: float = 0.3, iterations: int = 40
) -> np.ndarray:
    """Push a grid path away from obstacles where its clearance is below body radius + ``pad``
    (an elastic band: clearance gradient plus Laplacian smoothing, end points fixed). A grid cell
    0.1 m off the axis of a 0.5 m slot is enough to make the reactive set hit its sides."""
    pts, _ = _densify(path, 0.05)
    if len(pts) < 3:
        return pts
    planar = _planar(problem) is not None
    dims = 2 if planar else 3
    r = problem.model.body_radius

    def clearance(q: np.ndarray) -> np.ndarray:
        return problem.box_index.clearance(q, problem.bounds_lo, problem.bounds_hi, dims)

    eps = 1e-3
    steps = np.zeros((dims, 3))
    steps[np.arange(dims), np.arange(dims)] = eps
    # A point without a deficit never moves again (its push and smoothing are zero), so its
    # clearances stay what they were: only the points that had a deficit are queried again.
    active = np.ones(len(pts) - 2, bool)
    c_all = np.empty((1 + 2 * dims, len(pts) - 2))
    for _ in range(iterations):
        inner = pts[1:-1]
        idx = np.flatnonzero(active)
        q = inner[idx]
        # the clearance and its central differences, in one query
        probes = [q] + [q + sign * steps[d] for d in range(dims) for sign in (1.0, -1.0)]
        c_all[:, idx] = clearance(np.concatenate(probes)).reshape(1 + 2 * dims, len(idx))
        c0 = c_all[0]
        grad = np.zeros_like(inner)
        for d in range(dims):
            grad[:, d] = (c_all[1 + 2 * d] - c_all[2 + 2 * d]) / (2 * eps)
        deficit = np.clip(r + pad - c0, 0.0, None)
        if not np.any(deficit > 0.0):
            break  # every point has its clearance: nothing moves from here on
        push = grad * np.minimum(deficit, 0.02)[:, None]
        smooth = 0.5 * (pts[:-2] + pts[2:]) - inner
        moved = inner + push + 0.3 * smooth * (deficit > 0)[:, None]
        active = deficit > 0.0
        # never move a point closer to an obstacle than the body (the others stay where they are)
        ok = np.ones(len(inner), bool)
        ok[active] = clearance(moved[active]) >= np.minimum(c0[active], r)
        pts[1:-1] = np.where(ok[:, None], moved, inner)
    return pts


def initial_guess(
    problem: PlanningProblem, secure: bool = False, speed_fraction: float | None = None
) -> Guess:
    """Graph search on the belief, centred in narrow places, then a time scaling (visibility-aware
    for the secure planner)."""
    path = centre_path(problem, graph_path(problem))
    frac = problem.options.guess_speed_fraction if speed_fraction is None else speed_fraction
    guess = profile_guess(problem, path, frac, secure)
    return _uncrawled_guess(problem, guess, frac) if secure and _crawls(problem, guess) else guess


def _crawls(problem: PlanningProblem, guess: Guess) -> bool:
    """Whether the guess crawls somewhere between its ends (no faster speed was visible there)."""
    speeds = np.linalg.norm(np.asarray(problem.model.velocity(guess.states[1:-1])), axis=-1)
    return bool(len(speeds)) and float(speeds.min()) <= 2.0 * CRAWL_SPEED


def _uncrawled_guess(problem: PlanningProblem, guess: Guess, frac: float) -> Guess:
    """The fastest of the time scalings of the candidate paths that let the camera see first
    (:func:`secure3d.planning.visible_paths.candidate_paths`) if its final time is at most
    :data:`CANDIDATE_GAIN` times the crawling ``guess``'s, else ``guess``."""
    from secure3d.planning.visible_paths import candidate_paths

    pts, arc = _densify(guess.path, 0.1)
    tries = [
        profile_guess(problem, path, frac, True) for path in candidate_paths(problem, pts, arc)
    ]
    best = min(tries, key=lambda g: g.final_time, default=guess)
    return best if best.final_time <= CANDIDATE_GAIN * guess.final_time else guess


def clearance_field(problem: PlanningProblem) -> tuple[np.ndarray, np.ndarray, float]:
    """The grid behind the graph search (centres, clearance, cell size), for plots and tests."""
    return _clearance_grid(problem, problem.options.grid_resolution, _planar(problem))


def guess_from_plan(problem: PlanningProblem, warm: PlanResult, t_offset: float) -> Guess:
    """The previous plan from ``t_offset`` on: its later nodes kept as they are where the NLP takes
    a time grid (IPOPT) and they fit, else resampled on evenly spaced nodes."""
    args = (problem.model, warm.times, warm.states, warm.controls, t_offset)
    kept = remainder_keeping_nodes(*args) if problem.options.solver == Solver.IPOPT else None
    times, X, U = kept if kept is not None else resample(*args, problem.options.nodes)
    X[0] = problem.x0
    return Guess(times=times, states=X, controls=U, path=X[:, :3])


def guess_along_plan(
    problem: PlanningProblem, planner: str, other: PlanResult, t_offset: float
) -> Guess:
    """Another plan's path from ``t_offset`` on (its node positions after that time, from the
    problem's start), time-scaled as the graph-search guess is (:func:`profile_guess`)."""
    later = other.positions[other.times > t_offset + 1e-9]
    path = np.vstack([problem.start_position[None], later if len(later) else problem.goal[None]])
    frac = 1.0 if planner == Planner.BASELINE else problem.options.guess_speed_fraction
    return profile_guess(problem, path, frac, planner == Planner.SECURE)


__all__ = [
    "Guess",
    "NoPathError",
    "clearance_field",
    "graph_path",
    "guess_along_plan",
    "guess_from_plan",
    "initial_guess",
    "profile_guess",
]
