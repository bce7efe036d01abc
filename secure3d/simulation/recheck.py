"""Re-certifying the rest of a plan in flight, when a camera frame revealed new obstacles."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from secure3d.planning.problem import Planner

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.result import PlanResult
    from secure3d.simulation.loop import Loop

__all__ = ["Recheck", "path_clearance", "plan_unsafe"]


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


@dataclass(eq=False)
class Recheck:
    """A plan being re-certified in flight: its sampled manoeuvres (map-independent), the obstacle
    boxes it last passed against and what observed each manoeuvre point then (``Certificate.views``;
    None until it first passed). ``window`` is the same for the part before a known failure while
    a replan is deferred: (the failure's plan time, the views, lo, hi) of the last window passed."""

    plan: PlanResult
    sampled: object
    views: np.ndarray | None = None
    lo: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    hi: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    window: tuple | None = None


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
        rec = Recheck(
            plan, cert.sampled, cert.views, plan_problem_.boxes_lo, plan_problem_.boxes_hi
        )
    else:
        rec = Recheck(plan, sample_plan(plan, judged))
    loop.rechecks[id(plan)] = rec
    while len(loop.rechecks) > 4:
        loop.rechecks.popitem(last=False)
    return rec


def _window_unsafe(
    rec: Recheck, plan: PlanResult, judged: object, t_rel: float, t_until: float
) -> tuple[str, float] | None:
    """:func:`plan_unsafe` of the window ``[t_rel, t_until)`` before a known failure: against the
    added boxes alone when the same window passed last time and the boxes only grew since
    (:func:`~secure3d.planning.recertify.views_after_adding`, sound), else by the certificate."""
    from secure3d.planning.certificate import certify
    from secure3d.planning.recertify import views_after_adding

    lo, hi = judged.boxes_lo, judged.boxes_hi
    if rec.window is not None and rec.window[0] == t_until:
        _, views, old_lo, old_hi = rec.window
        if _grew_from(lo, hi, old_lo, old_hi):
            n = len(old_lo)
            views = views_after_adding(
                views, rec.sampled, judged, lo[n:], hi[n:], t_from=t_rel, t_until=t_until
            )
            if views is not None:
                rec.window = (t_until, views, lo, hi)
                return None
    cert = certify(
        plan, judged, t_from=t_rel, t_until=t_until, sampled=rec.sampled, first_only=True
    )
    if cert.ok:
        rec.window = (t_until, cert.views, lo, hi)
        return None
    first = cert.first_violation
    return str(first), float(first.time)


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
    from secure3d.planning.certificate import certify
    from secure3d.planning.recertify import views_after_adding

    if loop.planner == Planner.SECURE:
        judged = dataclasses.replace(plan_problem_, boxes_lo=lo, boxes_hi=hi)
        rec = _record(loop, plan, judged, plan_problem_)
        if np.isfinite(t_until):
            # known to fail at t_until: judge the window before it, up to its first failure (the
            # views of the whole rest stay those of its last full pass)
            return _window_unsafe(rec, plan, judged, t_rel, t_until)
        n = len(rec.lo)
        if rec.views is not None and _grew_from(lo, hi, rec.lo, rec.hi):
            # the boxes only grew since the plan last passed: check what the new ones touch
            views = views_after_adding(rec.views, rec.sampled, judged, lo[n:], hi[n:], t_from=t_rel)
            if views is not None:
                rec.views, rec.lo, rec.hi = views, lo, hi
                return None
        # only where the rest first fails matters (a pass judges every point, views and all)
        cert = certify(plan, judged, t_from=t_rel, sampled=rec.sampled, first_only=True)
        if cert.ok:
            rec.views, rec.lo, rec.hi = cert.views, lo, hi
            return None
        first = cert.first_violation
        return str(first), float(first.time) if first is not None else t_rel
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
