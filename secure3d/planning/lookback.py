"""Look-back assignment and obstacle-slot selection, evaluated in numpy on the current iterate.

The paper ties node i to node j = i - Δi (eq. NLP) and leaves relaxing this as future work. The
adaptive rule assigns each node the earlier node whose camera frustum contains its reactive set with
the largest margin, penalising views blocked by a known obstacle (or, as a cold plan's second try,
the latest with nearly that margin: :data:`NEAR_VIEW_FRACTION`), and the planner can re-solve
until the assignment is stable. Both rules keep the NLP's constraint a *sufficient* condition for the
paper's eq. FullConstraint, so the certificate judges them equally.
"""

from __future__ import annotations

import numpy as np

from secure3d.errors import PlanningError
from secure3d.geometry.frustum import frustum_halfspaces
from secure3d.geometry.polytope import box_pair_distances
from secure3d.planning.problem import Planner, PlanningProblem
from secure3d.planning.slot_screen import (
    INDEXED_MIN_BOXES,
    REFINED_PER_SLOT,
    SLOT_NEIGHBOURS,
    check_neighbours,
    indexed_slot_boxes,
    nearest_slots,
    neighbour_minimum,
    screened_pairs,
)

#: Penalty (m) on a candidate camera whose line of sight to the reactive set crosses a known obstacle.
OCCLUSION_PENALTY = 5.0


def node_geometry(problem: PlanningProblem, states: np.ndarray) -> dict[str, np.ndarray]:
    """Reactive ellipsoids and camera poses at the nodes: centres (K,3), shapes (K,3,3), R (K,3,3), o (K,3)."""
    model, family = problem.model, problem.family
    C, M = family.ellipsoid_batch(states)
    R, o = (np.asarray(a, dtype=float) for a in model.camera_pose(states))
    P = np.asarray(model.position(states), dtype=float)
    return {"C": np.asarray(C, float), "M": np.asarray(M, float), "R": R, "o": o, "P": P}


def frustum_margins(
    problem: PlanningProblem, geo: dict[str, np.ndarray], owner: np.ndarray | None = None
) -> np.ndarray:
    """(n_ellipsoids, n_cameras) margin of ellipsoid i inside camera j's frustum (min over faces;
    >= 0 inside). With ``owner`` (n_ellipsoids,) non-decreasing ints, only the pairs with
    ``j < owner[i]`` (the cameras before it) are computed, the others are -inf, by a compiled loop
    (:func:`~secure3d.planning._margin_kernel.earlier_frustum_margins`; the guess's speed caps ask
    for some 10^5-10^6 pairs): the same values to rounding (a few 1e-15 m)."""
    A, b = frustum_halfspaces(geo["R"], geo["o"], problem.frustum)  # (n_cam, F, 3), (n_cam, F)
    C, M = geo["C"], geo["M"]
    if owner is None:
        return _margins(A, b, C, M)
    from secure3d.planning._margin_kernel import earlier_frustum_margins

    owner = np.asarray(owner)
    if owner.shape != (len(C),) or np.any(np.diff(owner) < 0):
        raise PlanningError("frustum_margins: owner must be one non-decreasing int per ellipsoid")
    first = np.searchsorted(owner, np.arange(len(A)), side="right").astype(np.int64)
    f64 = np.ascontiguousarray
    return earlier_frustum_margins(
        f64(A, dtype=float), f64(b, dtype=float), f64(C, dtype=float), f64(M, dtype=float), first
    )


def _margins(A: np.ndarray, b: np.ndarray, C: np.ndarray, M: np.ndarray) -> np.ndarray:
    """(n, m) margins of ellipsoids (C (n, 3), M (n, 3, 3)) inside frusta (A (m, F, 3), b (m, F))."""
    # support of E_i along each face normal of frustum j: n.c_i + |M_i n|
    nc = np.einsum("jfd,id->ijf", A, C)
    Mn = np.einsum("iab,jfb->ijfa", M, A)
    support = nc + np.linalg.norm(Mn, axis=-1)
    return (b[None, :, :] - support).min(axis=-1)


def start_margins(problem: PlanningProblem, geo: dict[str, np.ndarray]) -> np.ndarray:
    """(K,) margin of each node's ellipsoid inside the observed start box (exact support test)."""
    extent = np.linalg.norm(geo["M"], axis=1)  # |M e_d| per axis d
    up = problem.start_region_hi - geo["C"] - extent
    down = geo["C"] - problem.start_region_lo - extent
    return np.minimum(up, down).min(axis=1)


def occluded(problem: PlanningProblem, geo: dict[str, np.ndarray]) -> np.ndarray:
    """(n_ellipsoids, n_cameras) True where a segment from camera j to ellipsoid i (centre or an
    axis tip) crosses a known obstacle box."""
    K, n_cam = len(geo["C"]), len(geo["o"])
    if len(problem.boxes_lo) == 0:
        return np.zeros((K, n_cam), bool)
    tips = sight_tips(geo["C"], geo["M"])  # (K, 7, 3)
    p0 = np.broadcast_to(geo["o"][None, :, None, :], (K, n_cam, 7, 3)).reshape(-1, 3)
    p1 = np.broadcast_to(tips[:, None, :, :], (K, n_cam, 7, 3)).reshape(-1, 3)
    hit = problem.box_index.segments_blocked(p0, p1)
    return hit.reshape(K, n_cam, 7).any(axis=2)


def sight_tips(C: np.ndarray, M: np.ndarray) -> np.ndarray:
    """(n, 7, 3) the points a camera must see of each ellipsoid (centres C (n, 3), shapes
    M (n, 3, 3)): its centre and 0.9 of the way to either end of each axis."""
    if np.ndim(C) != 2 or np.shape(C)[1:] != (3,) or np.shape(M) != (len(C), 3, 3):
        raise PlanningError(
            f"sight_tips: C (n, 3) and M (n, 3, 3), got {np.shape(C)}, {np.shape(M)}"
        )
    tips = [C] + [C + s * 0.9 * M[:, :, a] for a in range(3) for s in (1.0, -1.0)]
    return np.stack(tips, axis=1)


def fixed_assignment(K: int, steps: int) -> tuple[int, ...]:
    """The paper's rule j = i - Δi; nodes before Δi must lie in the start region (-1)."""
    return tuple(i - steps if i - steps >= 0 else -1 for i in range(K))


def best_views(
    problem: PlanningProblem, states: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each node's best earlier view on ``states``: (best j per node, -1 = start region; its margin;
    the margin of every (node, view) pair, start region in the last column)."""
    geo = node_geometry(problem, states)
    fm = frustum_margins(problem, geo)
    if problem.options.occlusion:
        fm = fm - OCCLUSION_PENALTY * occluded(problem, geo)
    K = len(states)
    i, j = np.arange(K)[:, None], np.arange(K)[None, :]
    allowed = j < i  # earlier views only
    span = problem.options.max_span
    if span is not None:
        allowed &= i - j <= span
    fm = np.where(allowed, fm, -np.inf)
    table = np.concatenate([fm, start_margins(problem, geo)[:, None]], axis=1)
    col = np.argmax(table[:, ::-1], axis=1)  # ties go to the start region
    best_col = K - col
    best_j = np.where(best_col == K, -1, best_col)
    return best_j, table[np.arange(K), best_col], table


#: The adaptive rule's second choice of views, which a cold plan tries when the solve from its
#: first choice fails (``solve.plan_problem``): each node tied to the latest earlier view holding at
#: least this fraction of its best view's margin on the guess. The best view is often the earliest
#: (a far camera frames the set with the most room), and long look-backs tie far-apart nodes
#: together. Measured (``benchmarks/results/closed_loop_session30.md``): a quadrotor's plans from
#: rest before a 0.83 m gap, every node tied to the start's view, ran out of every 10 s budget in
#: three of 200 campaign runs; with the near views they solve in 40 iterations. As the first choice
#: it lost eight other runs of the same campaign (certificate rejections between the first nodes).
NEAR_VIEW_FRACTION = 0.9


def adaptive_assignment(
    problem: PlanningProblem, states: np.ndarray, near_fraction: float | None = None
) -> tuple[tuple[int, ...], np.ndarray]:
    """Each node's view on ``states``: its best earlier view (the start region or the camera whose
    frustum holds its reactive set with the largest margin); with ``near_fraction`` (in (0, 1]),
    for a node whose best view is a camera with more than the planner's margin, the latest earlier
    camera holding at least that fraction of the best margin. Returns (assignment, the chosen
    views' margins)."""
    views = best_views(problem, states)
    out = _assigned(views, problem.options.margin, near_fraction)
    K = len(states)
    chosen = views[2][np.arange(K), np.where(out < 0, K, out)]
    return tuple(int(j) for j in out), chosen


def near_views_differ(problem: PlanningProblem, states: np.ndarray, near_fraction: float) -> bool:
    """Whether :func:`adaptive_assignment` with ``near_fraction`` ties some node on ``states`` to
    another view than without it (one view table for both)."""
    views = best_views(problem, states)
    margin = problem.options.margin
    return not np.array_equal(
        _assigned(views, margin, None), _assigned(views, margin, near_fraction)
    )


def _assigned(
    views: tuple[np.ndarray, np.ndarray, np.ndarray], margin: float, near_fraction: float | None
) -> np.ndarray:
    """(K,) views of :func:`adaptive_assignment` from :func:`best_views`' answer."""
    best_j, best, table = views
    K = len(best_j)
    out = best_j.copy()
    out[0] = -1
    if near_fraction is not None:
        if not 0.0 < near_fraction <= 1.0:
            raise PlanningError(f"near_fraction: must be in (0, 1], got {near_fraction!r}")
        for i in range(1, K):
            if out[i] >= 0 and best[i] > margin:
                near = np.flatnonzero(table[i, :K] >= max(margin, near_fraction * best[i]))
                out[i] = int(near.max())
    return out


def refine_assignment(
    problem: PlanningProblem, states: np.ndarray, current: tuple[int, ...], min_gain: float = 0.05
) -> tuple[int, ...]:
    """Adaptive rule between solves: move node i to a better earlier view only where that view
    already holds on ``states`` with the required margin and beats the current one by ``min_gain``
    (so the previous solution stays feasible and warm-starts the next solve)."""
    best_j, best, table = best_views(problem, states)
    out = list(current)
    for i in range(1, len(states)):
        cur = table[i, current[i]]  # column -1 is the start region
        if (
            best_j[i] != current[i]
            and best[i] >= problem.options.margin
            and best[i] >= cur + min_gain
        ):
            out[i] = int(best_j[i])
    return tuple(out)


def _hull_samples(
    problem: PlanningProblem, planner: str, states: np.ndarray, assignment: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """What :func:`_hull_box_distances` screens: per node, sample points (K, P, 3) and the reach
    (K,) subtracted from their distances."""
    o = problem.options
    K = len(states)
    geo = node_geometry(problem, states)
    if planner == Planner.SECURE:
        reach = np.linalg.norm(geo["M"], ord=2, axis=(1, 2))
        samples = []
        for k in range(K):
            j = assignment[k]
            if o.occlusion and j >= 0:
                samples.append(np.linspace(geo["o"][j], geo["C"][k], 6))
            else:
                samples.append(np.repeat(geo["C"][k][None], 6, axis=0))
        pts = np.stack(samples)  # (K, 6, 3)
    else:
        reach = np.full(K, problem.model.body_radius)
        pts = geo["P"][:, None, :]
    return np.ascontiguousarray(pts, dtype=float), np.asarray(reach, float)


def _hull_box_distances(
    problem: PlanningProblem, planner: str, states: np.ndarray, assignment: tuple[int, ...]
) -> np.ndarray:
    """(K, n_boxes) screening distance from what node k constrains to every known box: the body
    (baseline) or samples of the line-of-sight hull from camera j to E_k minus its largest
    semi-axis (secure)."""
    pts, reach = _hull_samples(problem, planner, states, assignment)
    # compiled, bit for bit min_box_distance_all(...).reshape(K, -1, n).min(axis=1) - reach: the
    # full rows, as select_slots' argsort breaks ties by them
    from secure3d.geometry._box_kernels import hull_screen

    lo, hi = problem.box_index.lo, problem.box_index.hi
    return hull_screen(pts, reach, lo, hi)


def constrained_sets(
    problem: PlanningProblem, planner: str, states: np.ndarray, assignment: tuple[int, ...] | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per node, what its obstacle rows keep clear, as (origins, centres, shapes, los) for
    :func:`~secure3d.geometry.polytope.box_pair_distances`: the line-of-sight hull from camera j to
    E_k (secure, seen from node j), E_k alone (secure, start region or no occlusion), or the segment
    from the body at node k to node k+1 (baseline: one plane keeps both clear)."""
    K = len(states)
    if planner == Planner.SECURE:
        geo = node_geometry(problem, states)
        j = np.full(K, -1) if assignment is None else np.asarray(assignment, dtype=int)
        los = (j >= 0) & bool(problem.options.occlusion)
        origins = np.where(los[:, None], geo["o"][np.maximum(j, 0)], geo["C"])
        return origins, geo["C"], geo["M"], los
    centres = np.asarray(problem.model.position(states), dtype=float)
    shapes = np.broadcast_to(problem.model.body_radius * np.eye(3), (K, 3, 3))
    return np.concatenate([centres[1:], centres[-1:]]), centres, shapes, np.ones(K, bool)


def _face_gaps(
    problem: PlanningProblem,
    sets: tuple[np.ndarray, ...],
    k_idx: np.ndarray,
    b_idx: np.ndarray,
) -> np.ndarray:
    """(n,) lower bounds on the distance from node ``k_idx[i]``'s constrained set
    (:func:`constrained_sets`: ``conv({o} ∪ E)``, ``E = {c + M z : |z| <= 1}``) to box
    ``b_idx[i]``: the widest gap along the box's six face normals. Along unit ``d`` the set reaches
    ``max(d.o, d.c + |M^T d|)`` and the box starts at ``min_y d.y``; any such gap is a separating
    slab, so the Euclidean distance is at least it (negative: no face separates them)."""
    origins, centres, shapes, _ = sets
    o, c = origins[k_idx], centres[k_idx]
    reach = np.linalg.norm(shapes[k_idx], axis=2)  # (n, 3): |M^T e_a| is the norm of row a
    up = np.maximum(o, c + reach)  # the set's extent along +e_a
    down = np.minimum(o, c - reach)  # and along -e_a
    gaps = np.maximum(problem.boxes_lo[b_idx] - up, down - problem.boxes_hi[b_idx])
    return gaps.max(axis=1)


def _exact_distances(
    problem: PlanningProblem,
    sets: tuple[np.ndarray, ...],
    k_idx: np.ndarray,
    b_idx: np.ndarray,
) -> np.ndarray:
    """Exact distance from node ``k_idx[i]``'s constrained set (:func:`constrained_sets`) to box
    ``b_idx[i]``."""
    origins, centres, shapes, los = sets
    return box_pair_distances(
        origins[k_idx],
        centres[k_idx],
        shapes[k_idx],
        problem.boxes_lo[b_idx],
        problem.boxes_hi[b_idx],
        los[k_idx],
    )


def _refine_distances(
    problem: PlanningProblem,
    states: np.ndarray,
    assignment: tuple[int, ...],
    screen: np.ndarray,
    keep: int,
) -> np.ndarray:
    """Replace the screening distances of each node's ``keep`` nearest boxes by exact ones (the
    screening subtracts the largest semi-axis, which ranks boxes poorly beside long reactive sets)."""
    sets = constrained_sets(problem, "secure", states, assignment)
    out = np.full_like(screen, np.inf)
    order = np.argsort(screen, axis=1)[:, :keep]
    k_idx = np.repeat(np.arange(len(states)), order.shape[1])
    b_idx = order.ravel()
    near = screen[k_idx, b_idx] <= problem.options.obstacle_radius
    k_idx, b_idx = k_idx[near], b_idx[near]
    out[k_idx, b_idx] = _exact_distances(problem, sets, k_idx, b_idx)
    return out


def _screened_below(
    problem: PlanningProblem,
    planner: str,
    states: np.ndarray,
    assignment: tuple[int, ...],
    limit: float,
) -> tuple[np.ndarray, np.ndarray]:
    """``(np.argwhere(d < limit), d[those])`` for the screen ``d`` of
    :func:`_hull_box_distances`: (f, 2) pairs and (f,) values (over many boxes, through the box
    index: the same pairs and values)."""
    if len(problem.boxes_lo) < INDEXED_MIN_BOXES:
        d = _hull_box_distances(problem, planner, states, assignment)
        flagged = np.argwhere(d < limit)
        return flagged, d[flagged[:, 0], flagged[:, 1]]
    pts, reach = _hull_samples(problem, planner, states, assignment)
    ks, js, vs = screened_pairs(problem, pts, reach, limit)
    below = vs < limit
    return np.stack([ks[below], js[below]], axis=1), vs[below]


#: Pairs whose exact distance :func:`slots_missing` computes per batch before checking for a miss.
_EXACT_CHUNK = 256
#: Slack (m) over the exact kernel's solve tolerance (measured <= 1.2e-9 below a face gap on 20,000
#: random pairs) with which a face gap must clear the limit to settle a pair without the kernel.
FACE_GAP_TOL = 1e-6


def _unslotted_pairs(
    problem: PlanningProblem,
    planner: str,
    states: np.ndarray,
    assignment: tuple[int, ...],
    slots: np.ndarray,
    limit: float,
) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, ...] | None]:
    """The (node, box) pairs (f, 2) screened below ``limit`` whose box is not in the node's
    ``slots``, with their screens (f,); for the secure planner (else None) also the constrained
    sets, and without the pairs that a face gap of at least the limit settles (a separating
    plane's gap bounds the distance from below; the exact kernel solves to ~1e-9, so a pair within
    FACE_GAP_TOL of the limit stays)."""
    flagged, screened = _screened_below(problem, planner, states, assignment, limit)
    boxes = np.concatenate([problem.boxes_lo, problem.boxes_hi], axis=1)[flagged[:, 1]]  # (f, 6)
    slotted = np.isclose(slots[flagged[:, 0]], boxes[:, None, :]).all(axis=-1).any(axis=1)
    flagged, screened = flagged[~slotted], screened[~slotted]
    if len(flagged) == 0 or planner != Planner.SECURE:
        return flagged, screened, None
    sets = constrained_sets(problem, planner, states, assignment)
    gapped = _face_gaps(problem, sets, flagged[:, 0], flagged[:, 1]) < limit + FACE_GAP_TOL
    return flagged[gapped], screened[gapped], sets


def slots_missing(
    problem: PlanningProblem,
    planner: str,
    states: np.ndarray,
    assignment: tuple[int, ...],
    slots: np.ndarray,
    slack: float = 0.0,
) -> bool:
    """Whether some box left out of a node's slots comes within ``margin + slack`` of what that
    node constrains on ``states`` (then the slots must be re-selected and the NLP re-solved). With
    ``slack`` 0: whether ``states`` violate a row of the NLP with every box."""
    if len(problem.boxes_lo) == 0:
        return False
    limit = problem.options.margin + slack
    flagged, screened, sets = _unslotted_pairs(problem, planner, states, assignment, slots, limit)
    if sets is None:
        return bool(len(flagged))
    # the screening bound is loose for elongated reactive sets: confirm with exact distances,
    # nearest screened pairs first, stopping at the first pair below the limit (the same answer)
    flagged = flagged[np.argsort(screened, kind="stable")]
    for start in range(0, len(flagged), _EXACT_CHUNK):
        part = flagged[start : start + _EXACT_CHUNK]
        if np.any(_exact_distances(problem, sets, part[:, 0], part[:, 1]) < limit):
            return True
    return False


#: A solution is re-solved with re-selected slots (:func:`slots_stale`) only when a box left out
#: of them comes within this fraction of the planner's margin of what a node constrains. A box
#: between that and the margin leaves the node less of its buffer against tracking error, never
#: below the certificate's own bound of 0, and the certificate judges every box. Measured
#: (``benchmarks/bench_map_scale.py --plan-by-size``, geb079 at 8 cm and refined to 4 cm): the
#: re-solves this spares found left-out boxes 15-19 mm away against a 20 mm margin and cost 25-30
#: cold iterations, a quarter of the call, for a final time equal to 4 digits.
SLOT_TOLERANCE = 0.5


def slots_stale(
    problem: PlanningProblem,
    planner: str,
    states: np.ndarray,
    assignment: tuple[int, ...],
    slots: np.ndarray,
) -> bool:
    """Whether a solution ``states`` must be re-solved with re-selected slots: a box left out of
    ``slots`` comes within ``(1 - SLOT_TOLERANCE) * margin`` of what a node constrains."""
    slack = -SLOT_TOLERANCE * problem.options.margin
    return slots_missing(problem, planner, states, assignment, slots, slack=slack)


def left_out_boxes(
    problem: PlanningProblem,
    states: np.ndarray,
    assignment: tuple[int, ...],
    slots: np.ndarray,
    limit: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Every (node, box) pair (f, 2) of the secure planner whose box is not in the node's
    ``slots`` (K, S, 6) and comes within ``limit`` of what the node constrains on ``states``, with
    the exact distances (f,) (what :func:`slots_missing` stops at the first of)."""
    none = np.zeros((0, 2), np.int64), np.zeros(0)
    if len(problem.boxes_lo) == 0:
        return none
    flagged, _, sets = _unslotted_pairs(problem, Planner.SECURE, states, assignment, slots, limit)
    if sets is None or len(flagged) == 0:
        return none
    d = _exact_distances(problem, sets, flagged[:, 0], flagged[:, 1])
    below = d < limit
    return flagged[below], d[below]


def with_left_out_boxes(
    problem: PlanningProblem,
    states: np.ndarray,
    assignment: tuple[int, ...],
    slots: np.ndarray,
    limit: float,
) -> np.ndarray:
    """``slots`` (K, S, 6) of the secure planner with each box :func:`left_out_boxes` finds put in
    its node's slot whose box is farthest from what the node constrains, nearest boxes first, while
    that slot's box is farther than it.

    :func:`select_slots` ranks a node's candidates by a screen that is loose beside long reactive
    sets, and only its ``REFINED_PER_SLOT`` S nearest by exact distance; a box the solution came
    close to can stay outside them at every re-selection, so that re-solves repeat the same
    solution (measured on ``geb079_hidden_crate``: three re-solves of 41, 23 and 20 iterations,
    each leaving a box 6.6 mm away against a 20 mm margin). Putting the boxes in by their exact
    distance ends that."""
    pairs, d = left_out_boxes(problem, states, assignment, slots, limit)
    if len(pairs) == 0:
        return slots
    origins, centres, shapes, los = constrained_sets(problem, Planner.SECURE, states, assignment)
    out = slots.copy()
    S = slots.shape[1]
    far = empty_slots(problem, slots)  # (K, S)
    for k in np.unique(pairs[:, 0]):
        mine = np.flatnonzero(pairs[:, 0] == k)
        mine = mine[np.argsort(d[mine], kind="stable")]
        kk = np.full(S, k)
        held = box_pair_distances(
            origins[kk], centres[kk], shapes[kk], out[k, :, 0:3], out[k, :, 3:6], los[kk]
        )
        held = np.where(far[k], np.inf, held)
        for i in mine:
            s = int(np.argmax(held))
            if held[s] <= d[i]:
                break
            j = pairs[i, 1]
            out[k, s, 0:3], out[k, s, 3:6] = problem.boxes_lo[j], problem.boxes_hi[j]
            held[s] = d[i]
    return out


def empty_slot_lo(problem: PlanningProblem) -> np.ndarray:
    """Lower corner of the small box an empty slot holds, far outside the world (inactive rows)."""
    return np.asarray(problem.bounds_hi, dtype=float) + 1e3


def empty_slots(problem: PlanningProblem, slots: np.ndarray) -> np.ndarray:
    """(K, S) bool: which of ``slots`` (K, S, 6) hold the far box of an empty slot."""
    if np.ndim(slots) != 3 or np.shape(slots)[-1] != 6:
        raise PlanningError(f"empty_slots: slots must have shape (K, S, 6), got {np.shape(slots)}")
    return np.all(np.isclose(slots[:, :, 0:3], empty_slot_lo(problem)), axis=-1)


def select_slots(
    problem: PlanningProblem,
    planner: str,
    states: np.ndarray,
    assignment: tuple[int, ...],
    neighbours: int = SLOT_NEIGHBOURS,
) -> np.ndarray:
    """(K, S, 6) boxes [lo, hi] per node slot: the known obstacles nearest to what node k constrains
    (the body for the baseline; for the secure planner, the line-of-sight hull from camera j to
    E_k, or that of one of the ``neighbours`` nodes either side of it, at exact distances:
    ``slot_screen.SLOT_NEIGHBOURS``). Empty slots hold a small box far outside the world (its
    constraint is inactive)."""
    check_neighbours(neighbours, "select_slots: neighbours")
    o = problem.options
    K, S = len(states), o.obstacle_slots
    far = empty_slot_lo(problem)
    slots = np.empty((K, S, 6))
    slots[:, :, 0:3] = far
    slots[:, :, 3:6] = far + 0.1
    n = len(problem.boxes_lo)
    if n == 0:
        return slots
    directions = planner == Planner.SECURE and o.slot_pick == "directions"
    centres = node_geometry(problem, states)["C"] if directions else None
    if n >= INDEXED_MIN_BOXES:  # the nearest through the box index: the same choice
        pts, reach = _hull_samples(problem, planner, states, assignment)

        def exact(k_idx: np.ndarray, b_idx: np.ndarray) -> np.ndarray:
            sets = constrained_sets(problem, "secure", states, assignment)
            return _exact_distances(problem, sets, k_idx, b_idx)

        chosen = indexed_slot_boxes(problem, planner, pts, reach, exact, centres, neighbours)
    else:
        d = _hull_box_distances(problem, planner, states, assignment)
        if planner == Planner.SECURE:
            d = _refine_distances(problem, states, assignment, d, REFINED_PER_SLOT * S)
            d = neighbour_minimum(d, neighbours)
        chosen = nearest_slots(problem, d, S, centres)
    for k in range(K):
        for s, idx in enumerate(chosen[k]):
            if idx >= 0:
                slots[k, s, 0:3] = problem.boxes_lo[idx]
                slots[k, s, 3:6] = problem.boxes_hi[idx]
    return slots


def keep_slot_positions(previous: np.ndarray, slots: np.ndarray) -> np.ndarray:
    """``slots`` (K, S, 6) rearranged so that every box also in ``previous`` keeps its slot there.

    A slot's constraint rows and separation duals belong to the box in it; a re-selection that only
    reorders boxes would otherwise look like new obstacles to a warm start. Node sets are unchanged.
    """
    if previous is None or previous.shape != slots.shape:
        return slots
    out = slots.copy()
    for k in range(len(slots)):
        match = np.all(np.isclose(previous[k][:, None, :], slots[k][None, :, :]), axis=-1)  # (S, S)
        if not match.any():
            continue
        kept_new = np.zeros(slots.shape[1], bool)
        taken = np.zeros(slots.shape[1], bool)
        for s_old in range(slots.shape[1]):
            hits = np.flatnonzero(match[s_old] & ~kept_new)
            if len(hits):
                out[k, s_old] = slots[k, hits[0]]
                kept_new[hits[0]] = taken[s_old] = True
        out[k, ~taken] = slots[k, ~kept_new]
    return out


def min_box_distance_all(points: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n_points, n_boxes) Euclidean distance from points to boxes (0 inside)."""
    q = np.clip(points[:, None, :], lo[None], hi[None])
    return np.linalg.norm(points[:, None, :] - q, axis=-1)


__all__ = [
    "adaptive_assignment",
    "sight_tips",
    "near_views_differ",
    "constrained_sets",
    "empty_slot_lo",
    "empty_slots",
    "fixed_assignment",
    "frustum_margins",
    "keep_slot_positions",
    "left_out_boxes",
    "node_geometry",
    "occluded",
    "select_slots",
    "slots_missing",
    "slots_stale",
    "start_margins",
    "with_left_out_boxes",
]
