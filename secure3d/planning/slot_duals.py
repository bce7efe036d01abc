"""Where a solve starts the obstacle slots' separating duals, and which side one-sided duals take.

Every slot (node k, slot s) holds a box ``lo <= y <= hi`` and a dual ``lam >= 0`` on its faces
``+x, +y, +z, -x, -y, -z`` (``A = [I; -I]``, ``b = [hi; -lo]``, ``nu = A^T lam``). Its rows keep
what node k constrains clear of the box (:mod:`secure3d.planning.constraints`):

- ``lam.(A c - b) - |M nu| >= m``: the reactive set (the baseline: the body) ``{c + M z}``;
- ``lam.(A o - b) - pad >= m``: the apex ``o`` of the line-of-sight hull (the camera of the node
  it is seen from; ``pad = 0``), or for the baseline the body at node k+1 (``pad = |M nu|``).

Any dual-feasible ``lam`` makes the rows a sufficient condition, so a start dual only decides how
far from feasible the solver starts, never what it accepts.
"""

from __future__ import annotations

import numpy as np

from secure3d.errors import GeometryError
from secure3d.geometry.polytope import box_pair_distances
from secure3d.planning.lookback import constrained_sets, empty_slots, node_geometry
from secure3d.planning.problem import Planner, PlanningProblem

__all__ = ["dual_row_margins", "initial_duals", "slot_sides"]


def dual_row_margins(
    lam: np.ndarray,
    origins: np.ndarray,
    centres: np.ndarray,
    shapes: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    los: np.ndarray,
    apex_pad: bool = False,
) -> np.ndarray:
    """The smaller left-hand side of a slot's two rows (above) for each of ``n`` pairs.

    Parameters
    ----------
    lam : (n, 6) duals >= 0. origins, centres : (n, 3) the apex o and the set's centre c.
    shapes : (n, 3, 3) M. lo, hi : (n, 3) the boxes. los : (n,) bool, whether the apex row holds
    (a line-of-sight hull); without it only the set's row counts.
    apex_pad : the apex carries the set's shape too (the baseline's body at the next node).

    Returns
    -------
    (n,) float: ``min(lam.(A c - b) - |M nu|, lam.(A o - b) - pad)``.
    """
    lam = np.asarray(lam, dtype=float)
    n = len(lam)
    expected = {
        "lam": (lam, (n, 6)),
        "origins": (origins, (n, 3)),
        "centres": (centres, (n, 3)),
        "shapes": (shapes, (n, 3, 3)),
        "lo": (lo, (n, 3)),
        "hi": (hi, (n, 3)),
        "los": (los, (n,)),
    }
    for name, (value, shape) in expected.items():
        if np.shape(value) != shape:
            raise GeometryError(
                f"dual_row_margins: {name} must have shape {shape}, got {np.shape(value)}"
            )
    nu = lam[:, 0:3] - lam[:, 3:6]
    b = np.concatenate([hi, -lo], axis=1)
    spread = np.linalg.norm(np.einsum("nij,nj->ni", shapes, nu), axis=1)
    own = (lam * (np.concatenate([centres, -centres], axis=1) - b)).sum(axis=1) - spread
    apex = (lam * (np.concatenate([origins, -origins], axis=1) - b)).sum(axis=1)
    apex = apex - (spread if apex_pad else 0.0)
    return np.where(los, np.minimum(own, apex), own)


def _normal_duals(centres: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(K, S, 6): the unit outward normal at the box point nearest each node's centre (K, 3),
    split into its positive face components (so ``|A^T lam| = 1`` and ``lam.(A c - b)`` is the
    distance); from the box's middle when the centre lies inside it."""
    q = np.clip(centres[:, None, :], lo, hi)
    n = centres[:, None, :] - q
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    fallback = centres[:, None, :] - 0.5 * (lo + hi)
    n = np.where(norm > 1e-9, n, fallback)
    n = n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return np.concatenate([np.maximum(n, 0.0), np.maximum(-n, 0.0)], axis=-1)


def initial_duals(
    problem: PlanningProblem,
    planner: str,
    states: np.ndarray,
    slots: np.ndarray,
    assignment: tuple[int, ...],
) -> np.ndarray:
    """(K, S, 6) start duals for the slots' boxes ``slots`` (K, S, 6) on ``states`` (K, nx).

    The outward normal from each box to the node's centre (:func:`_normal_duals`). For the secure
    planner, where that dual leaves a row of the slot short of the margin but what the rows keep
    clear (the line-of-sight hull from the camera of node ``assignment[k]`` to E_k, or E_k alone) is
    clear of the box, its exact certifying dual instead: the normal ignores the camera, and so
    started two of every three occlusion rows violated by up to 2 m on geb079_hidden_crate, which
    the solver then spent tens of iterations repairing. Duals that already satisfy the rows stay
    (the exact one can lead the solver to another local optimum: thin_pole's 12.27 s plan became
    12.72 s with exact duals everywhere). The baseline keeps the normals.
    """
    lo, hi = slots[:, :, 0:3], slots[:, :, 3:6]
    if planner != Planner.SECURE:
        return _normal_duals(node_geometry(problem, states)["P"], lo, hi)
    # the secure planner's centres: node_geometry's "C", as constrained_sets returns them
    origins, centres, shapes, los = constrained_sets(problem, planner, states, assignment)
    lam = _normal_duals(centres, lo, hi)
    k_idx, s_idx = np.nonzero(~empty_slots(problem, slots))
    if not len(k_idx):
        return lam
    pair_lo, pair_hi = lo[k_idx, s_idx], hi[k_idx, s_idx]
    sets = (origins[k_idx], centres[k_idx], shapes[k_idx], pair_lo, pair_hi, los[k_idx])
    short = dual_row_margins(lam[k_idx, s_idx], *sets) < problem.options.margin
    if not short.any():
        return lam
    k_idx, s_idx = k_idx[short], s_idx[short]
    dist, exact = box_pair_distances(*(a[short] for a in sets), with_duals=True)
    clear = (dist > 0) & (np.abs(exact[:, 0:3] - exact[:, 3:6]).sum(axis=1) > 1e-9)
    lam[k_idx[clear], s_idx[clear]] = exact[clear]
    return lam


def slot_sides(
    problem: PlanningProblem,
    planner: str,
    states: np.ndarray,
    slots: np.ndarray,
    assignment: tuple[int, ...] | None = None,
) -> np.ndarray:
    """(K, S, 3) bool: for one-sided duals, whether each slot's dual acts on the box's upper face
    along each axis or on its lower face.

    The side is the one the optimal separating plane uses on ``states``: the exact dual of what the
    slot's rows constrain (the line-of-sight hull from camera j to E_k, or E_k alone, for the secure
    planner; the segment from the body at node k to node k+1 for the baseline). Where that dual has
    no component along an axis (or the sets touch), the side of the box's middle the set's centre
    lies on. Any choice is sound (weak duality holds for every dual-feasible lam); a poor one only
    makes the constraint conservative.
    """
    origins, centres, shapes, los = constrained_sets(problem, planner, states, assignment)
    middle = 0.5 * (slots[:, :, 0:3] + slots[:, :, 3:6])
    sides = centres[:, None, :] >= middle
    k_idx, s_idx = np.nonzero(~empty_slots(problem, slots))
    if len(k_idx):
        _, lam = box_pair_distances(
            origins[k_idx],
            centres[k_idx],
            shapes[k_idx],
            slots[k_idx, s_idx, 0:3],
            slots[k_idx, s_idx, 3:6],
            los[k_idx],
            with_duals=True,
        )
        nu = lam[:, 0:3] - lam[:, 3:6]
        decided = np.abs(nu) > 1e-6
        sides[k_idx, s_idx] = np.where(decided, nu > 0, sides[k_idx, s_idx])
    return sides
