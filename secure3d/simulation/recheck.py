"""Re-certifying the rest of a plan in flight, when a camera frame revealed new obstacles."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from secure3d.planning.problem import Planner

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.result import PlanResult
    from secure3d.simulation.loop import Loop

__all__ = ["Passed", "Recheck", "path_clearance", "plan_unsafe"]


def path_clearance(
    loop: Loop, plan: PlanResult, t_rel: float, lo: np.ndarray, hi: np.ndarray
) -> float:
    """Smallest distance from the rest of the planned body path to the boxes, minus the body radius."""
    from secure3d.geometry.box_index import BoxIndex
    from secure3d.planning.trajectory import interpolate

    t = np.arange(t_rel, plan.final_time, 0.02)
    if len(t) == 0 or len(lo) == 0:
        return float("inf")
    X, _ = interpolate(loop.model, plan.times, plan.states, plan.controls, t)
    P = np.asarray(loop.model.position(X), dtype=float)
    # 0 inside a box, as the body is then simply in contact
    dist = BoxIndex.of(lo, hi).min_distance(P)
    return float(np.maximum(dist, 0.0).min() - loop.model.body_radius)


@dataclass(frozen=True, eq=False)
class Passed:
    """A window of a plan that passed: judged before plan time ``until`` (``inf``: the whole rest)
    against the boxes ``lo, hi`` (n, 3), with ``views`` (``Certificate.views``: what observed each
    manoeuvre point)."""

    until: float
    views: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


@dataclass(eq=False)
class Recheck:
    """A plan being re-certified in flight: its sampled manoeuvres (map-independent) and, per
    window, its last pass (:class:`Passed`): ``rest`` for the whole rest of the plan (None until it
    first passed), ``window`` for the part before a known failure while a replan is deferred."""

    plan: PlanResult
    sampled: object
    rest: Passed | None = None
    window: Passed | None = None


def _grew_from(lo: np.ndarray, hi: np.ndarray, old_lo: np.ndarray, old_hi: np.ndarray) -> bool:
    """Whether the boxes ``lo, hi`` are ``old_lo, old_hi`` followed by others (they only grew)."""
    n = len(old_lo)
    return len(lo) >= n and np.array_equal(lo[:n], old_lo) and np.array_equal(hi[:n], old_hi)


def _record(loop: Loop, plan: PlanResult, judged: object, plan_problem_: object) -> Recheck:
    """The loop's :class:`Recheck` of ``plan`` (made on its first re-check, from its certificate
    when that passed against the boxes of ``plan_problem_``; the loop keeps the last four)."""
    from secure3d.planning.certificate import sample_plan

    rec = loop.rechecks.get(id(plan))
    if rec is not None and rec.plan is plan:
        return rec
    cert = plan.certificate
    if cert is not None and cert.ok and cert.sampled is not None:
        # certified when planned, against the boxes of the problem it was planned on
        lo, hi = plan_problem_.boxes_lo, plan_problem_.boxes_hi
        rec = Recheck(plan, cert.sampled, rest=Passed(np.inf, cert.views, lo, hi))
    else:
        rec = Recheck(plan, sample_plan(plan, judged))
    loop.rechecks[id(plan)] = rec
    while len(loop.rechecks) > 4:
        loop.rechecks.popitem(last=False)
    return rec


def _first_failure(
    rec: Recheck, judged: object, t_rel: float, t_until: float
) -> tuple[str, float] | None:
    """Where the plan of ``rec`` first fails in ``[t_rel, t_until)`` among ``judged``'s boxes (the
    failure and its plan time), or None. Against the added boxes alone when the same window passed
    last time and the boxes only grew since
    (:func:`~secure3d.planning.recertify.views_after_adding`, sound), else by the certificate (only
    where the window first fails matters; a pass judges every point, views and all)."""
    from secure3d.planning.certificate import certify
    from secure3d.planning.recertify import views_after_adding

    lo, hi = judged.boxes_lo, judged.boxes_hi
    last = rec.rest if np.isinf(t_until) else rec.window
    views = None
    if last is not None and last.until == t_until and _grew_from(lo, hi, last.lo, last.hi):
        n = len(last.lo)
        views = views_after_adding(
            last.views, rec.sampled, judged, lo[n:], hi[n:], t_from=t_rel, t_until=t_until
        )
    if views is None:
        cert = certify(
            rec.plan, judged, t_from=t_rel, t_until=t_until, sampled=rec.sampled, first_only=True
        )
        if not cert.ok:
            first = cert.first_violation
            return str(first), float(first.time) if first is not None else t_rel
        views = cert.views
    passed = Passed(t_until, views, lo, hi)
    if np.isinf(t_until):
        rec.rest = passed
    else:
        rec.window = passed
    return None


def plan_unsafe(
    loop: Loop,
    plan: PlanResult,
    plan_problem_: object,
    t_rel: float,
    lo: np.ndarray,
    hi: np.ndarray,
    t_until: float = np.inf,
) -> tuple[str, float] | None:
    """Why the rest of ``plan`` (from ``t_rel`` on) is not safe among the obstacle boxes ``lo, hi``
    (the updated belief), and the plan time from which it is not (the first manoeuvre that fails
    the certificate; ``inf`` for the baseline, which promises no manoeuvre), or None.
    ``plan_problem_`` is the problem the plan was planned (and certified) on. With a finite
    ``t_until`` (a secure plan already known to fail there, its replan deferred until before it)
    only the part before ``t_until`` is judged: None then means no earlier failure.

    A secure plan that already passed against a prefix of these boxes (the boxes only grew, as
    :meth:`Loop.judged_plus` grows them) is judged against the added boxes alone first
    (:func:`~secure3d.planning.recertify.views_after_adding`, sound); the full certificate runs
    only if that does not show it safe. So is the window before a known failure, once it passed."""
    if loop.planner == Planner.SECURE:
        judged = dataclasses.replace(plan_problem_, boxes_lo=lo, boxes_hi=hi)
        # with a finite t_until (known to fail there) the window before it, up to its first
        # failure; the whole rest keeps the views of its own last pass
        return _first_failure(_record(loop, plan, judged, plan_problem_), judged, t_rel, t_until)
    # The baseline only promises a collision-free path: react when the new evidence brings an obstacle
    # into the body's planned path.
    after = path_clearance(loop, plan, t_rel, lo, hi)
    before = path_clearance(loop, plan, t_rel, plan_problem_.boxes_lo, plan_problem_.boxes_hi)
    if after < 0.0 and after < before - 1e-3:
        return (
            f"an obstacle seen in flight blocks the planned path (clearance {after:+.3f} m)",
            np.inf,
        )
    return None


#: Default ``replan_defer`` of :func:`simulate` (s). Measured on the 200 hidden-obstacle variants of
#: the blind corner: see README ("Closed loop") and ``benchmarks/results/campaign_blind_corner.md``.
