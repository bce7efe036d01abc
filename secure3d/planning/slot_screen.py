"""The obstacle-slot screens of :mod:`~secure3d.planning.lookback` over many boxes, through the box
index, with the full screens' answers bit for bit.

:func:`~secure3d.planning.lookback.select_slots` and
:func:`~secure3d.planning.lookback.slots_missing` screen every (node, box) pair: a (K, m) matrix of
distances from samples of what node k constrains to box j (``hull_screen``), argsorted row by row.
Over a scanned building (19,000 merged boxes, K = 40) that is ~0.1 s of each plan call, although
only a row's nearest few boxes (within the slot radius) or its pairs below the margin are ever used.
Here the box index's tree yields just those, with the matrix's entries bit for bit
(:mod:`~secure3d.geometry._hull_near_kernel`):

- the pairs below a limit (``hull_near``) are the matrix's, in its row-major order
  (``np.argwhere``), so ``slots_missing`` gets the same pairs;
- the S nearest boxes of a row (``hull_nearest``: its S + 1 smallest entries, or
  ``REFINED_PER_SLOT`` S + 1 where the secure planner refines that many of them) are the full
  argsort's first S whenever their values are distinct: a sort of the full row can only order
  *equal* values differently (its tie order depends on the sort algorithm and on every other
  entry). A row where a tie could matter (among the first S + 1 values within the radius, or at
  the boundary of the refined ones) is ranked in full, as before: numpy sorts each row of a matrix
  as it sorts that row alone.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from secure3d.errors import PlanningError
from secure3d.planning.problem import Planner, PlanningProblem

__all__ = [
    "INDEXED_MIN_BOXES",
    "REFINED_PER_SLOT",
    "SLOT_CONE_DEG",
    "SLOT_NEIGHBOURS",
    "by_direction",
    "check_neighbours",
    "indexed_slot_boxes",
    "nearest_slots",
    "neighbour_minimum",
    "screened_pairs",
]

#: Boxes from which the screens go through the index (below, the matrix is as cheap).
INDEXED_MIN_BOXES = 256

#: The secure planner ranks a node's boxes by their exact distance from what the node constrains,
#: but computes it only for this many times S of the node's nearest by the screen (which subtracts
#: the largest semi-axis of the reactive set, so ranks boxes poorly beside a long one). With 2S,
#: geb079_hidden_crate's node 14 left out its two nearest boxes (0.121 and 0.124 m exactly; not
#: among the 16 nearest by the screen), and the solution went through them.
REFINED_PER_SLOT = 4

#: A node's slots hold the S boxes nearest to what it, or any node up to this many either side of
#: it, constrains (each box at its least distance over those nodes). A solution slides along its
#: guess: on geb079_hidden_crate node 13 of the solution came within the margin of boxes that on the
#: guess were node 14's two nearest and only node 13's 13th-15th, and the slot refresh this forced
#: cost 29 of the call's 87 iterations; with one neighbour, 0 of 53. Over the 23 shipped maps' cold
#: plans, 1,459 -> 1,274 iterations (2 neighbours: 1,391; benchmarks/results/session55.md).
SLOT_NEIGHBOURS = 1

#: ``slot_pick="directions"``: a box whose nearest point lies within this angle (deg) of a nearer
#: box's, seen from the node's reactive-set centre, waits until every direction has its nearest.
#: Over a scanned building a door jamb is a dozen merged voxel boxes, and a node's 8 nearest all
#: lay on one jamb while the solution moved towards the other (geb079_hidden_crate: a slot
#: refresh, 29 of its 80 cold iterations). 20 and 45 deg measured alike (session41.md).
SLOT_CONE_DEG = 30.0


def by_direction(
    centre: np.ndarray, lo: np.ndarray, hi: np.ndarray, ranked: np.ndarray, n: int
) -> np.ndarray:
    """Up to ``n`` of the boxes ``ranked`` (m,) (indices into ``lo``, ``hi`` (B, 3), nearest
    first), kept in that order: greedily each box whose direction from ``centre`` (3,) to its
    nearest point is more than SLOT_CONE_DEG from that of every box taken before it (a box holding
    ``centre`` always counts as a new direction), then the others, nearest first."""
    centre = np.asarray(centre, dtype=float)
    ranked = np.asarray(ranked, dtype=np.int64)
    if centre.shape != (3,) or not np.all(np.isfinite(centre)):
        raise PlanningError(f"by_direction: centre must be 3 finite numbers, got {centre!r}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise PlanningError(f"by_direction: n must be an integer >= 1, got {n!r}")
    if ranked.ndim != 1 or (len(ranked) and not 0 <= ranked.min() <= ranked.max() < len(lo)):
        raise PlanningError(f"by_direction: ranked must index the {len(lo)} boxes, got {ranked!r}")
    if len(ranked) <= n:
        return ranked
    v = np.clip(centre, lo[ranked], hi[ranked]) - centre
    norm = np.linalg.norm(v, axis=1)
    u = np.divide(v, norm[:, None], out=np.zeros_like(v), where=norm[:, None] > 0.0)
    cos_limit = np.cos(np.radians(SLOT_CONE_DEG))
    taken: list[int] = []
    for i in range(len(ranked)):
        if norm[i] == 0.0 or not taken or bool(np.all(u[taken] @ u[i] < cos_limit)):
            taken.append(i)
            if len(taken) == n:
                break
    rest = np.setdiff1d(np.arange(len(ranked)), taken)[: n - len(taken)]
    return ranked[np.sort(np.concatenate([np.asarray(taken, dtype=np.int64), rest]))]


def screened_pairs(
    problem: PlanningProblem, pts: np.ndarray, reach: np.ndarray, limit: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(k, j, value) of the entries of ``hull_screen(pts, reach, boxes)`` at most ``limit``, by k
    then j ascending."""
    from secure3d.geometry._hull_near_kernel import hull_near

    index = problem.box_index
    pts = np.ascontiguousarray(pts, dtype=float)
    reach = np.ascontiguousarray(reach, dtype=float)
    return hull_near(pts, reach, float(limit), index.lo, index.hi, *index.tree)


def _nearest(
    problem: PlanningProblem, pts: np.ndarray, reach: np.ndarray, limit: float, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(k, j, value): per row of ``hull_screen(pts, reach, boxes)`` its ``n`` smallest entries at
    most ``limit`` (the values exact; among equal ones, which boxes is not defined), by value."""
    from secure3d.geometry._hull_near_kernel import hull_nearest

    index = problem.box_index
    pts = np.ascontiguousarray(pts, dtype=float)
    reach = np.ascontiguousarray(reach, dtype=float)
    return hull_nearest(pts, reach, float(limit), int(n), index.lo, index.hi, *index.tree)


def _smallest(values: np.ndarray, n: int, limit: float, ordered: bool) -> np.ndarray | None:
    """Positions of the ``n`` smallest ``values`` at most ``limit``, ascending, as any argsort of a
    row holding them (and only larger values besides) ranks them; None if a tie (or a NaN) makes
    that depend on the sort: among the first n + 1 values (``ordered``), or only between the n-th
    and the next (the set, not its order, counts)."""
    order = np.argsort(values, kind="stable")
    v = values[order]
    if np.isnan(v).any():
        return None
    head = v[: n + 1]
    ties = (head[1:] == head[:-1]) & (head[:-1] <= limit)
    tie = ties.any() if ordered else bool(len(head) > n and ties[n - 1])
    if tie:
        return None
    keep = order[:n]
    return keep[v[:n] <= limit]


def _first(row: np.ndarray, n: int, limit: float) -> np.ndarray:
    """``argsort(row)[:n]``, those at most ``limit``: a full row's ranking, ties as the matrix's
    row-wise argsort breaks them (numpy sorts each row of a matrix as it sorts that row alone)."""
    order = np.argsort(row)[:n]
    return order[row[order] <= limit]


def _screen_row(problem: PlanningProblem, pts: np.ndarray, reach: np.ndarray, k: int) -> np.ndarray:
    """Row k of the full screen (``hull_screen``'s entries over every box)."""
    from secure3d.geometry._box_kernels import hull_screen

    index = problem.box_index
    return hull_screen(pts[k : k + 1], reach[k : k + 1], index.lo, index.hi)[0]


def _refined(
    problem: PlanningProblem,
    screened: tuple[np.ndarray, ...],
    rows: list[np.ndarray],
    exact: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`~secure3d.planning.lookback._refine_distances` on the screened pairs: each row's
    ``REFINED_PER_SLOT`` S nearest by the screen (a row with a tie at the last of them: by its full
    screen row), with their exact distances (``exact(k_idx, b_idx)``); per node (boxes, exact
    distances)."""
    pts, reach, js, vs = screened
    S, R = problem.options.obstacle_slots, problem.options.obstacle_radius
    n = REFINED_PER_SLOT * S
    picked = []
    for k, row in enumerate(rows):
        keep = _smallest(vs[row], n, R, ordered=False)
        if keep is None:
            picked.append(_first(_screen_row(problem, pts, reach, k), n, R))
        else:
            picked.append(js[row[keep]])
    k_idx = np.repeat(np.arange(len(rows)), [len(b) for b in picked])
    b_idx = np.concatenate(picked).astype(np.int64)
    distances = exact(k_idx, b_idx) if len(k_idx) else np.zeros(0)
    ends = np.cumsum([len(b) for b in picked])
    return [(b, distances[e - len(b) : e]) for b, e in zip(picked, ends, strict=True)]


def check_neighbours(n: object, name: str) -> None:
    """Raise a PlanningError naming ``name`` unless ``n`` is an integer >= 0 (a window of nodes)."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 0:
        raise PlanningError(f"{name} must be an integer >= 0, got {n!r}")


def neighbour_minimum(d: np.ndarray, n: int) -> np.ndarray:
    """(K, m) distances ``d`` (K, m), each row replaced by the elementwise least of rows k - n to
    k + n (those that exist): how near box j comes to what node k or a neighbour constrains."""
    d = np.asarray(d, dtype=float)
    if d.ndim != 2:
        raise PlanningError(f"neighbour_minimum: d must have shape (K, m), got {d.shape}")
    check_neighbours(n, "neighbour_minimum: n")
    out = d.copy()
    for i in range(1, min(n, len(d) - 1) + 1):
        np.minimum(out[i:], d[:-i], out=out[i:])
        np.minimum(out[:-i], d[i:], out=out[:-i])
    return out


def _neighbour_rows(
    ranked: list[tuple[np.ndarray, np.ndarray]], n: int
) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`neighbour_minimum` on sparse rows: per node the (boxes, values) of rows k - n to
    k + n, each box once at its least value, ordered by value (then box); ``ranked`` itself for
    n = 0."""
    if n == 0:
        return ranked
    out = []
    for k in range(len(ranked)):
        near = ranked[max(0, k - n) : k + n + 1]
        boxes = np.concatenate([b for b, _ in near]).astype(np.int64)
        values = np.concatenate([v for _, v in near]).astype(float)
        order = np.lexsort((boxes, values))  # by value, then box
        boxes, values = boxes[order], values[order]
        first = np.sort(np.unique(boxes, return_index=True)[1])  # each box at its least value
        out.append((boxes[first], values[first]))
    return out


def indexed_slot_boxes(
    problem: PlanningProblem,
    planner: str,
    pts: np.ndarray,
    reach: np.ndarray,
    exact: Callable[[np.ndarray, np.ndarray], np.ndarray],
    centres: np.ndarray | None = None,
    neighbours: int = SLOT_NEIGHBOURS,
) -> np.ndarray:
    """(K, S) box per node slot (-1: empty) as :func:`~secure3d.planning.lookback.select_slots`
    picks them from the full screen of the samples ``pts`` (K, P, 3) and ``reach`` (K,), found
    through the box index (a row whose ranking a tie decides is ranked in full); the secure planner
    ranks its ``REFINED_PER_SLOT`` S nearest by ``exact(k_idx, b_idx)``, their exact distances, at
    their least over the node and ``neighbours`` nodes either side (:func:`neighbour_minimum`), and
    with the nodes' reactive-set ``centres`` (K, 3) picks S of its 2S nearest
    :func:`by_direction`."""
    check_neighbours(neighbours, "indexed_slot_boxes: neighbours")
    m = len(problem.boxes_lo)
    o = problem.options
    K, S, R = len(pts), o.obstacle_slots, o.obstacle_radius
    # per row the n + 1 smallest entries within the radius: the ranking and a tie at its end
    secure = planner == Planner.SECURE
    ks, js, vs = _nearest(problem, pts, reach, R, (REFINED_PER_SLOT * S if secure else S) + 1)
    bounds = np.searchsorted(ks, np.arange(K + 1))
    rows = [np.arange(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    if secure:
        ranked = _neighbour_rows(_refined(problem, (pts, reach, js, vs), rows, exact), neighbours)
    else:
        ranked = [(js[row], vs[row]) for row in rows]
    chosen = np.full((K, min(S, m)), -1, dtype=np.int64)
    n_rank = 2 * S if secure and centres is not None else S
    for k, (boxes, values) in enumerate(ranked):
        keep = _smallest(values, n_rank, R, ordered=True)
        if keep is not None:
            sel = boxes[keep]
        elif secure:  # the refined row as select_slots writes it: inf but its refined boxes
            full = np.full(m, np.inf)
            full[boxes] = values
            sel = _first(full, n_rank, R)
        else:
            sel = _first(_screen_row(problem, pts, reach, k), S, R)
        if n_rank > S:
            sel = by_direction(centres[k], problem.boxes_lo, problem.boxes_hi, sel, S)
        chosen[k, : len(sel)] = sel
    return chosen


def nearest_slots(
    problem: PlanningProblem, d: np.ndarray, S: int, centres: np.ndarray | None
) -> np.ndarray:
    """(K, S) slots (-1: empty) from the distances ``d`` (K, m): per node its S nearest within the
    slot radius, or with ``centres`` (K, 3) S of its 2S nearest picked
    :func:`by_direction`."""
    n_rank = S if centres is None else 2 * S
    order = np.argsort(d, axis=1)[:, :n_rank]
    chosen = np.where(
        np.take_along_axis(d, order, axis=1) <= problem.options.obstacle_radius, order, -1
    )
    if centres is None:
        return chosen
    out = np.full((len(d), min(S, d.shape[1])), -1, dtype=np.int64)
    for k, row in enumerate(chosen):
        sel = by_direction(centres[k], problem.boxes_lo, problem.boxes_hi, row[row >= 0], S)
        out[k, : len(sel)] = sel
    return out
