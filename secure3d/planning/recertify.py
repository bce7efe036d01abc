"""Re-certifying a plan that passed once the known obstacles only grew: a sound shortcut of
:func:`~secure3d.planning.certificate.certify` that judges only what the added boxes take part in."""

from __future__ import annotations

import numpy as np

from secure3d.errors import PlanningError
from secure3d.geometry.polytope import min_box_distance
from secure3d.planning.certificate import (
    PAST_VIEW,
    CertificateSettings,
    SampledPlan,
    _box_index,
    _check_window,
    _clear_views,
    _stored_views,
    _view_origins,
    _with_past_views,
)

__all__ = ["views_after_adding"]


def views_after_adding(
    views: np.ndarray,
    sampled: SampledPlan,
    problem: object,
    added_lo: np.ndarray,
    added_hi: np.ndarray,
    *,
    t_from: float = 0.0,
    t_until: float = np.inf,
    settings: CertificateSettings | None = None,
) -> np.ndarray | None:
    """Re-certify, from ``t_from`` on (and before ``t_until``), a plan that passed with ``views``
    (a passing :attr:`Certificate.views`, from ``sampled``) once the boxes (``added_lo``,
    ``added_hi``) joined the obstacles it passed against; ``problem`` holds all of them now. A
    sound shortcut of :func:`certify` (with the same window) for a map whose obstacles only grew.

    More obstacles never help a plan, so only the checks the added boxes take part in can fail:
    every judged manoeuvre point must stay clear of them by the body radius, and the sight cone
    that observed it must stay clear of them. Points whose cone an added box blocks get the view
    search of :func:`certify` again, against all the boxes. Returns the views that now observe each
    point (a passing certificate against all the boxes would hold such views), or None when a point
    is not shown safe so (an added box near a manoeuvre, no clear view left, a point not judged
    before): then :func:`certify` in full, which also names the violation.
    """
    from secure3d.geometry._box_kernels import cone_box_blocked_any

    _check_window(t_from, t_until)
    settings = settings or CertificateSettings()
    tol, r = settings.tolerance, problem.model.body_radius
    if views is None or len(views) != len(sampled.points):
        return None
    t = sampled.times[sampled.owner]
    judge = np.flatnonzero((t >= t_from - 1e-9) & (t < t_until - 1e-9))
    if np.any(views[judge] == -2):
        return None
    added_lo, added_hi = _added_boxes(added_lo, added_hi)
    if not len(added_lo):
        return views
    points = sampled.points[judge]
    if np.any(np.maximum(min_box_distance(points, added_lo, added_hi), 0.0) - r < -tol):
        return None
    seen = judge[(views[judge] >= 0) | (views[judge] <= PAST_VIEW)]
    origins = _view_origins(views[seen], sampled, problem)
    if origins is None:
        return None
    blocked = seen[
        cone_box_blocked_any(
            np.ascontiguousarray(origins),
            np.ascontiguousarray(sampled.points[seen]),
            added_lo,
            added_hi,
            float(r),
        )
    ]
    if not len(blocked):
        return views
    k, R, o = _with_past_views(problem, sampled.rotations, sampled.origins)
    found, best, _, view = _clear_views(
        sampled.points[blocked],
        sampled.owner[blocked] + k,
        R,
        o,
        problem.frustum,
        r,
        problem.boxes_lo,
        problem.boxes_hi,
        tol,
        _box_index(problem),
    )
    if not np.all(found & (best >= -tol)):
        return None
    out = views.copy()
    out[blocked] = _stored_views(view, k)
    return out


def _added_boxes(added_lo: object, added_hi: object) -> tuple[np.ndarray, np.ndarray]:
    """The boxes :func:`views_after_adding` is given, as contiguous (n, 3) arrays, validated."""
    added_lo = np.ascontiguousarray(np.asarray(added_lo, dtype=float))
    added_hi = np.ascontiguousarray(np.asarray(added_hi, dtype=float))
    if (
        added_lo.ndim != 2
        or added_lo.shape[1:] != (3,)
        or added_hi.shape != added_lo.shape
        or not (np.all(np.isfinite(added_lo)) and np.all(added_hi >= added_lo))
    ):
        raise PlanningError(
            "views_after_adding: added boxes must be finite (n, 3) corners with hi >= lo, got"
            f" lo {added_lo.shape}, hi {added_hi.shape}"
        )
    return added_lo, added_hi
