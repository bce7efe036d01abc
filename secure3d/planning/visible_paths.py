"""Guess paths that let the camera see first: where the shortest path's guess would crawl.

The visibility-aware time scaling of the guess (:func:`secure3d.planning.guess.secure_speed_caps`)
caps the speed at each path point so that its reactive set lies in an earlier view. Where no speed
is visible, it crawls (at :data:`secure3d.planning.guess.CRAWL_SPEED`), and IPOPT keeps the crawl
or fails from it. Two kinds of start make the shortest path crawl at once, both with a narrow
vertical view, and each has a candidate path here that keeps the shortest path's course but lets
an earlier view see what follows:

- **Held altitude** (:func:`held_altitude_paths`). The body's sphere (radius r) fits the vertical
  field of view only from ``d = r / sin(vfov / 2)`` away, so a path that climbs or descends at once
  leaves every earlier view. ``beam_3d``'s plan from rest, ducking under a beam 4 m ahead seen
  through a 30 deg vertical view, took 20.6 s along the shortest path (its guess 28.4 s, most of it
  at the crawl floor) and 7.7 s from a guess that first flies level (guess 5.0 s). The candidates
  keep the path's horizontal course and blend its height from the start's to the path's own over a
  ramp of arc length.
- **Stepped back** (:func:`stepped_back_paths`). The start region holds a reactive set up to its
  edge, and the start's view holds it only from where the set fits the view's height: with a
  34 deg vertical view a quadrotor's set at rest (0.30 m half-size) fits from 1.25 m ahead, the
  1 m start region holds it up to 0.7 m, and no view covers what lies between. A camera further
  back does: the candidates first back away from the view, inside the start region, then fly the
  path. A forest variant with that camera: the plan from rest ran out of its 10 s budget (T 25 s);
  backed 0.6 m away first, it is certified in 2.5 s (T 6.8 s).

The guess keeps whichever time scaling is fastest (:func:`secure3d.planning.guess.initial_guess`).
A held-altitude candidate must keep the clearance of the path it came from (or the body radius plus
the planner's margin, where that was more); a stepped-back one stays where the start region holds
its reactive set at rest. Which one is flown is still the NLP's and the certificate's decision.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from secure3d.errors import PlanningError

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.problem import PlanningProblem

__all__ = [
    "AT_REST",
    "BACK_OFF_FRACTIONS",
    "RAMP_LENGTHS",
    "RAMP_STARTS",
    "candidate_paths",
    "held_altitude_paths",
    "level_distance",
    "stepped_back_paths",
]

#: Where the height ramp starts and how long it is, in units of :func:`level_distance`.
RAMP_STARTS = (1.3, 2.6)
RAMP_LENGTHS = (2.0, 4.0)
#: How far a stepped-back candidate backs away: fractions of the farthest the start region allows.
BACK_OFF_FRACTIONS = (0.5, 1.0)
#: Fastest start (m/s) a stepped-back candidate is made for.
AT_REST = 0.05
#: Shortest back-off worth a candidate (m), and the step of the search for the farthest one (m).
MIN_BACK_OFF, BACK_OFF_STEP = 0.1, 0.05


def _path(points: object, arc: object = None) -> tuple[np.ndarray, np.ndarray | None]:
    """``points`` as (n, 3) finite floats and ``arc`` as (n,) finite, non-decreasing floats from
    0 (if given); a :class:`PlanningError` names the bad argument."""
    pts = np.asarray(points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.all(np.isfinite(pts)):
        raise PlanningError(f"points: must be a finite (n, 3) array, got shape {pts.shape}")
    if arc is None:
        return pts, None
    s = np.asarray(arc, dtype=float)
    if s.shape != (len(pts),) or not np.all(np.isfinite(s)):
        raise PlanningError(f"arc: must be {len(pts)} finite arc lengths, got shape {s.shape}")
    if len(s) and (s[0] != 0.0 or np.any(np.diff(s) < 0.0)):
        raise PlanningError("arc: must start at 0 and never decrease")
    return pts, s


def level_distance(problem: PlanningProblem) -> float:
    """Distance (m) from which the body's sphere fits the camera's vertical field of view:
    ``body_radius / sin(vfov / 2)``."""
    return float(problem.model.body_radius / np.sin(0.5 * problem.frustum.vfov))


def held_altitude_paths(
    problem: PlanningProblem, points: np.ndarray, arc: np.ndarray
) -> list[np.ndarray]:
    """Candidate paths (each (n, 3)) along ``points`` (n, 3) at arc lengths ``arc`` (n,, from 0)
    whose height is the start's up to ``s0`` and the path's own from ``s0 + L`` on, linear in
    between, for every (s0, L) of :data:`RAMP_STARTS` x :data:`RAMP_LENGTHS` times
    :func:`level_distance`. Only candidates whose height differs from the path's by a body radius
    somewhere (less keeps the reactive set about as high as before), end where it ends, stay
    inside the bounds and keep its clearance are returned (none for a planar model)."""
    pts, s = _path(points, arc)
    if problem.model.planar or len(pts) < 3:
        return []
    d = level_distance(problem)
    clear = problem.box_index.clearance(pts, problem.bounds_lo, problem.bounds_hi)
    need = np.minimum(clear, problem.model.body_radius + problem.options.margin)
    out: list[np.ndarray] = []
    for start in RAMP_STARTS:
        for length in RAMP_LENGTHS:
            w = np.clip((s - start * d) / (length * d), 0.0, 1.0)
            z = pts[0, 2] + w * (pts[:, 2] - pts[0, 2])
            if w[-1] < 1.0 or np.max(np.abs(z - pts[:, 2])) < problem.model.body_radius:
                continue
            cand = pts.copy()
            cand[:, 2] = z
            if np.all(
                problem.box_index.clearance(cand, problem.bounds_lo, problem.bounds_hi) >= need
            ):
                out.append(cand)
    return out


def stepped_back_paths(problem: PlanningProblem, points: np.ndarray) -> list[np.ndarray]:
    """Candidate paths (each (n + 1, 3)) that first back away from the start's view, straight
    along its horizontal optical axis, then return to the start and follow ``points`` (n, 3, from
    the start): one per fraction of :data:`BACK_OFF_FRACTIONS` of the farthest back-off whose
    reactive set at rest lies in the start region by the planner's margin all the way. None for a
    robot that heads where it goes (it would have to turn round), for one that is moving (faster
    than :data:`AT_REST`: it would brake and reverse), or if the start region allows less than
    :data:`MIN_BACK_OFF`."""
    from secure3d.planning.lookback import node_geometry, start_margins

    model = problem.model
    pts, _ = _path(points)
    moving = float(np.linalg.norm(model.velocity(problem.x0))) > AT_REST
    if model.heading_follows_path or moving or len(pts) < 2:
        return []
    yaw = float(model.yaw(problem.x0))
    back = -np.array([np.cos(yaw), np.sin(yaw), 0.0])
    span = float(np.linalg.norm(problem.start_region_hi - problem.start_region_lo))
    steps = np.arange(1, int(np.ceil(span / BACK_OFF_STEP)) + 1)
    along = pts[0] + (BACK_OFF_STEP * steps)[:, None] * back
    rest = model.initial_states(along, np.zeros_like(along), np.full(len(along), yaw))
    inside = start_margins(problem, node_geometry(problem, rest)) >= problem.options.margin
    reach = BACK_OFF_STEP * (int(np.argmin(inside)) if not inside.all() else len(inside))
    if reach < MIN_BACK_OFF:
        return []
    return [
        np.vstack([pts[:1], pts[0] + frac * reach * back, pts])
        for frac in BACK_OFF_FRACTIONS
        if frac * reach >= MIN_BACK_OFF
    ]


def candidate_paths(
    problem: PlanningProblem, points: np.ndarray, arc: np.ndarray
) -> list[np.ndarray]:
    """Every candidate of both kinds for the path ``points`` (n, 3) at arc lengths ``arc`` (n,)."""
    return held_altitude_paths(problem, points, arc) + stepped_back_paths(problem, points)
