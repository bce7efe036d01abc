"""The certificate's view search as one compiled loop (see :func:`certificate.certify`).

For every manoeuvre point it computes how well each earlier camera sees the body ball around it (in
the camera frame, from the FOV angles and the sensor range) and tries the cameras best first until
one has a sight cone no known obstacle box meets. The numpy form of the same search built
(points x cameras) temporaries and sorted all of them; here only as many cameras are ranked as are
tried, which is one or two for almost every point.
"""

from __future__ import annotations

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.geometry._box_index_kernels import _STACK, _cone_box_gap
from secure3d.geometry._box_kernels import _cone_gap, _hits

#: Cameras found by repeated maximum scans before a point's remaining cameras are sorted instead.
_SCANS = 16
#: Boxes that blocked a recent sight cone, tried first for the next one (most blocked cones of a
#: search are blocked by the same few boxes).
_RECENT = 4


#: The work of one sight-cone test in :func:`best_clear_views`, in units of one camera's margin
#: (measured on an occluded 70 s plan, 57,000 points x up to 3,566 cameras: a margin ~2 ns, a cone
#: test ~1.1 µs).
CONE_WORK = 512

#: A gap this far above 0 (m) stays above 0 through any rounding of the search's evaluations.
_SURE = 1e-9


@numba.njit(cache=True, inline="always")
def _gap_and_slope(p0, d0, d1, d2, t, lo, hi, radius):  # pragma: no cover - compiled
    """The cone gap g(t) = dist(p0 + t d, box) - t radius and its derivative (0, 0 inside)."""
    q0, q1, q2 = p0[0] + t * d0, p0[1] + t * d1, p0[2] + t * d2
    e0 = q0 - min(max(q0, lo[0]), hi[0])
    e1 = q1 - min(max(q1, lo[1]), hi[1])
    e2 = q2 - min(max(q2, lo[2]), hi[2])
    dist = np.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    if dist == 0.0:
        return 0.0, 0.0
    return dist - t * radius, (e0 * d0 + e1 * d1 + e2 * d2) / dist - radius


#: Tangent cuts tried before falling back to the golden-section search.
_CUTS = 6


@numba.njit(cache=True)
def _surely_clear(p0, d0, d1, d2, lo, hi, radius):  # pragma: no cover - compiled
    """A sufficient test that the golden-section search of ``_cone_box_gap`` finds no gap < 0.

    g(t) = dist(p0 + t d, box) - t radius is convex (and smooth outside the box), so its tangents
    bound it from below (Kelley's cutting planes in one dimension): the minimum over [0, 1] lies in
    a bracket [a, b] whose tangents slope down at a and up at b, and min(La, Lb) at their crossing
    (clamped) is a lower bound however the crossing is rounded. Each cut moves one end of the
    bracket to the crossing. Any evaluated gap <= _SURE: not shown (the search decides)."""
    ga, sa = _gap_and_slope(p0, d0, d1, d2, 0.0, lo, hi, radius)
    gb, sb = _gap_and_slope(p0, d0, d1, d2, 1.0, lo, hi, radius)
    a, b = 0.0, 1.0
    for _ in range(_CUTS):
        if ga <= _SURE or gb <= _SURE:
            return False
        if sa >= 0.0:  # g rises from a on: its minimum on [a, b] is g(a)
            return True
        if sb <= 0.0:
            return True
        t = min(max((gb - sb * b - ga + sa * a) / (sa - sb), a), b)
        if min(ga + sa * (t - a), gb + sb * (t - b)) > _SURE:
            return True
        gt, st = _gap_and_slope(p0, d0, d1, d2, t, lo, hi, radius)
        if st < 0.0:
            a, ga, sa = t, gt, st
        else:
            b, gb, sb = t, gt, st
    return False


@numba.njit(cache=True)
def _blocks(p0, c, radius, lo, hi, j, glo, ghi):  # pragma: no cover - compiled
    """Box j meets conv({p0} ∪ B(c, radius)): the per-box test of ``cone_blocked``, with the same
    answer (a box the tangent bound shows clear the search would find clear too)."""
    d0, d1, d2 = c[0] - p0[0], c[1] - p0[1], c[2] - p0[2]
    for a in range(3):
        glo[a] = lo[j, a] - radius
        ghi[a] = hi[j, a] + radius
    if not _hits(p0[0], p0[1], p0[2], d0, d1, d2, glo, ghi):
        return False
    if _cone_gap(p0, d0, d1, d2, 1.0, lo[j], hi[j], radius) < 0.0:
        return True  # a term of the search's minimum: the body ball itself meets the box
    if _surely_clear(p0, d0, d1, d2, lo[j], hi[j], radius):
        return False
    return _cone_box_gap(p0, d0, d1, d2, lo[j], hi[j], radius) < 0.0


@numba.njit(cache=True)
def _cone_blocked_by(p0, c, radius, lo, hi, tree, stack, glo, ghi, recent):  # pragma: no cover
    """``_box_index_kernels.cone_blocked`` (the same answer: whether some box meets the sight
    cone), trying the boxes in ``recent`` first and remembering the box that blocks."""
    for r in range(recent.shape[0]):
        j = recent[r]
        if j >= 0 and _blocks(p0, c, radius, lo, hi, j, glo, ghi):
            return True
    if lo.shape[0] == 0:
        return False
    perm, nlo, nhi, child, start, count = tree
    d0, d1, d2 = c[0] - p0[0], c[1] - p0[1], c[2] - p0[2]
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        for a in range(3):
            glo[a] = nlo[node, a] - radius
            ghi[a] = nhi[node, a] + radius
        if not _hits(p0[0], p0[1], p0[2], d0, d1, d2, glo, ghi):
            continue
        ch = child[node]
        if ch >= 0:
            stack[top], stack[top + 1] = ch, ch + 1
            top += 2
            continue
        for k in range(start[node], start[node] + count[node]):
            if _blocks(p0, c, radius, lo, hi, perm[k], glo, ghi):
                for r in range(recent.shape[0] - 1, 0, -1):
                    recent[r] = recent[r - 1]
                recent[0] = perm[k]
                return True
    return False


@numba.njit(cache=True)
def best_clear_views(  # pragma: no cover - compiled
    points,
    owner,
    R,
    o,
    sin_h,
    cos_h,
    sin_v,
    cos_v,
    sides,
    far,
    far_range,
    radius,
    lo,
    hi,
    tree,
    tol,
    top,
    found,
    best,
    raw,
    view,
    first,
    max_work,
):
    """For each ball B(points[i], radius), i = first, first + 1, ..., and the cameras (R, o) of
    samples 0 .. owner[i] - 1, writes:

    - ``raw[i]``: the best view margin min(horizontal side, vertical side, near, far) - radius.
      The side planes ``x = t z + offset`` have unit normals (cos, -sin) in (x, z), ``sin_h =
      sin(atan t)`` and so on for the horizontal and vertical pairs (t: the image edge's tangent
      less an observed field of view's ``side_shrink``), ``sides = (margin, offset, near)``
      (:class:`~secure3d.geometry.frustum.PinholeFrustum`'s ``side_margin``, ``side_offset``,
      ``near``; all 0: the image's border, no near face);
    - ``found[i]``, ``best[i]``: the best margin among cameras whose sight cone is clear of the boxes
      (lo, hi) (their spatial index ``tree``: :attr:`BoxIndex.tree`, exact), trying cameras by
      decreasing margin and giving up past the ``top`` best once margins are <= -tol (then no
      camera can pass);
    - ``view[i]``: that camera (-1 if none was found).

    ``found``, ``best``, ``raw``, ``view`` (n,) are the caller's, filled from ``first`` on with
    False, -inf, -inf, -1 (margins stay -inf where no earlier camera exists). Stops after the
    point at which ``max_work`` units of work were done since ``first`` (a camera's margin is one
    unit, a sight-cone test :data:`CONE_WORK`; a point's search is never cut) and returns the index
    of the next point to judge (n when all are done): a caller with a deadline looks at the clock
    between calls. One point costs at most (1 + CONE_WORK) units per earlier camera.
    """
    n, c = points.shape[0], R.shape[0]
    m = np.empty(c)
    used = np.zeros(c, dtype=np.bool_)
    grow_lo = np.empty(3)
    grow_hi = np.empty(3)
    stack = np.empty(_STACK, dtype=np.int64)
    recent = np.full(_RECENT, -1, dtype=np.int64)
    margin, offset, near = sides[0], sides[1], sides[2]
    work = 0
    for i in range(first, n):
        if work >= max_work:
            return i
        k = min(owner[i], c)
        if k <= 0:
            continue
        work += k
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        top_margin = -np.inf
        for j in range(k):
            dx, dy, dz = px - o[j, 0], py - o[j, 1], pz - o[j, 2]
            # camera frame (x right, y down, z forward): R_j^T (p - o_j)
            x = R[j, 0, 0] * dx + R[j, 1, 0] * dy + R[j, 2, 0] * dz
            y = R[j, 0, 1] * dx + R[j, 1, 1] * dy + R[j, 2, 1] * dz
            z = R[j, 0, 2] * dx + R[j, 1, 2] * dy + R[j, 2, 2] * dz
            side_h = z * sin_h - abs(x) * cos_h + offset * cos_h - margin
            side_v = z * sin_v - abs(y) * cos_v + offset * cos_v - margin
            f = far - (np.sqrt(x * x + y * y + z * z) if far_range else z)
            if near > 0.0:
                f = min(f, z - near)
            m[j] = min(side_h, side_v, f) - radius
            used[j] = False
            if m[j] > top_margin:
                top_margin = m[j]
        raw[i] = top_margin
        order = np.empty(0, dtype=np.int64)
        cursor = 0
        for rank in range(k):
            if rank < _SCANS:  # next best camera by a scan: cheap while few are tried
                cam, cand = -1, -np.inf
                for j in range(k):
                    if not used[j] and (cam < 0 or m[j] > cand):
                        cam, cand = j, m[j]
            else:  # many tried: sort once, then walk the order past the cameras already tried
                if rank == _SCANS:
                    order = np.argsort(-m[:k])
                while used[order[cursor]]:
                    cursor += 1
                cam = order[cursor]
                cand = m[cam]
            if rank >= top and cand <= -tol:
                break
            used[cam] = True
            work += CONE_WORK
            if not _cone_blocked_by(
                o[cam], points[i], radius, lo, hi, tree, stack, grow_lo, grow_hi, recent
            ):
                found[i] = True
                best[i] = cand
                view[i] = cam
                break
    return n
