"""Guess paths that hold the start's height a while before they climb or descend.

A camera with a narrow vertical view cannot see a reactive set just above or below it: the body's
sphere (radius r) fits the vertical field of view only from ``d = r / sin(vfov / 2)`` away. A
shortest path that starts to climb or descend at once therefore puts its first manoeuvres where no
earlier view saw them. The visibility-aware time scaling of the guess
(:func:`secure3d.planning.guess.secure_speed_caps`) then crawls there, and IPOPT keeps the crawl:
``beam_3d``'s plan from rest, ducking under a beam 4 m ahead seen through a 30 deg vertical view,
took 20.6 s along the shortest path (its guess 28.4 s, most of it at the 0.05 m/s floor) and
7.7 s from a guess that first flies level (guess 5.0 s).

:func:`held_altitude_paths` keeps a path's horizontal course and blends its height from the
start's to the path's own over a ramp of arc length; the guess keeps whichever time scaling is
fastest (:func:`secure3d.planning.guess.initial_guess`). A candidate must keep the clearance of the
path it came from (or the body radius plus the planner's margin, where that was more), so it is as
collision-free as the grid path; which one is flown is still the NLP's and the certificate's
decision.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.problem import PlanningProblem

__all__ = ["RAMP_LENGTHS", "RAMP_STARTS", "held_altitude_paths", "level_distance"]

#: Where the height ramp starts and how long it is, in units of :func:`level_distance`.
RAMP_STARTS = (1.3, 2.6)
RAMP_LENGTHS = (2.0, 4.0)
#: A candidate whose height differs from the path's by less than this everywhere is the same path (m).
SAME_PATH = 0.05


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
    :func:`level_distance`. Only candidates that differ from ``points`` by at least
    :data:`SAME_PATH`, end where it ends, stay inside the bounds and keep its clearance are
    returned (none for a planar model)."""
    pts = np.asarray(points, dtype=float)
    s = np.asarray(arc, dtype=float)
    if problem.model.planar or len(pts) < 3:
        return []
    d = level_distance(problem)
    clear = _clearance(problem, pts)
    need = np.minimum(clear, problem.model.body_radius + problem.options.margin)
    out: list[np.ndarray] = []
    for start in RAMP_STARTS:
        for length in RAMP_LENGTHS:
            w = np.clip((s - start * d) / (length * d), 0.0, 1.0)
            z = pts[0, 2] + w * (pts[:, 2] - pts[0, 2])
            if w[-1] < 1.0 or np.max(np.abs(z - pts[:, 2])) < SAME_PATH:
                continue
            cand = pts.copy()
            cand[:, 2] = z
            if np.all(_clearance(problem, cand) >= need):
                out.append(cand)
    return out


def _clearance(problem: PlanningProblem, pts: np.ndarray) -> np.ndarray:
    """(n,) distance of each point to the bounds and the known obstacles (negative inside)."""
    c = np.minimum(pts - problem.bounds_lo, problem.bounds_hi - pts).min(axis=1)
    if len(problem.boxes_lo):
        c = problem.box_index.min_distance(pts, c)
    return c
