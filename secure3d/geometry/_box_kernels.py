"""Compiled loops for the box queries that the planner and certificate call millions of times.

Each mirrors a numpy reference in :mod:`secure3d.geometry.polytope` (tested to agree); the loops
exist only because the (n segments x m boxes x 3 axes) temporaries of the numpy form dominate the
planner's run time.
"""

from __future__ import annotations

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)


@numba.njit(cache=True)
def _hits(a0, a1, a2, d0, d1, d2, lo, hi) -> bool:  # pragma: no cover - compiled
    t0, t1 = 0.0, 1.0
    for axis in range(3):
        s = a0 if axis == 0 else (a1 if axis == 1 else a2)
        d = d0 if axis == 0 else (d1 if axis == 1 else d2)
        if d == 0.0:
            if s < lo[axis] or s > hi[axis]:
                return False
            continue
        ta = (lo[axis] - s) / d
        tb = (hi[axis] - s) / d
        if ta > tb:
            ta, tb = tb, ta
        if ta > t0:
            t0 = ta
        if tb < t1:
            t1 = tb
        if t0 > t1:
            return False
    return True


@numba.njit(cache=True)
def segment_box_matrix(p0, p1, lo, hi):  # pragma: no cover - compiled
    n, m = p0.shape[0], lo.shape[0]
    out = np.zeros((n, m), dtype=np.bool_)
    for i in range(n):
        d0, d1, d2 = p1[i, 0] - p0[i, 0], p1[i, 1] - p0[i, 1], p1[i, 2] - p0[i, 2]
        for j in range(m):
            out[i, j] = _hits(p0[i, 0], p0[i, 1], p0[i, 2], d0, d1, d2, lo[j], hi[j])
    return out


@numba.njit(cache=True)
def segment_box_any(p0, p1, lo, hi):  # pragma: no cover - compiled
    n, m = p0.shape[0], lo.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        d0, d1, d2 = p1[i, 0] - p0[i, 0], p1[i, 1] - p0[i, 1], p1[i, 2] - p0[i, 2]
        for j in range(m):
            if _hits(p0[i, 0], p0[i, 1], p0[i, 2], d0, d1, d2, lo[j], hi[j]):
                out[i] = True
                break
    return out


@numba.njit(cache=True)
def min_signed_distance(points, lo, hi):  # pragma: no cover - compiled
    n, m = points.shape[0], lo.shape[0]
    out = np.full(n, np.inf)
    for i in range(n):
        best = np.inf
        for j in range(m):
            out2 = 0.0
            inside = -np.inf
            for axis in range(3):
                q = max(lo[j, axis] - points[i, axis], points[i, axis] - hi[j, axis])
                if q > 0.0:
                    out2 += q * q
                if q > inside:
                    inside = q
            d = np.sqrt(out2) if out2 > 0.0 else min(inside, 0.0)
            if d < best:
                best = d
        out[i] = best
    return out


@numba.njit(cache=True)
def inside_any(points, lo, hi):  # pragma: no cover - compiled
    """Whether each point lies strictly inside some box (``min_signed_distance < 0``)."""
    n, m = points.shape[0], lo.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        for j in range(m):
            if lo[j, 0] < x < hi[j, 0] and lo[j, 1] < y < hi[j, 1] and lo[j, 2] < z < hi[j, 2]:
                out[i] = True
                break
    return out


@numba.njit(cache=True)
def _point_box_distance(x, y, z, lo, hi) -> float:  # pragma: no cover - compiled
    dx = max(lo[0] - x, 0.0, x - hi[0])
    dy = max(lo[1] - y, 0.0, y - hi[1])
    dz = max(lo[2] - z, 0.0, z - hi[2])
    return np.sqrt(dx * dx + dy * dy + dz * dz)


@numba.njit(cache=True)
def _cone_gap(p0, d0, d1, d2, t, lo, hi, radius) -> float:  # pragma: no cover - compiled
    return _point_box_distance(p0[0] + t * d0, p0[1] + t * d1, p0[2] + t * d2, lo, hi) - t * radius


@numba.njit(cache=True)
def _cone_blocked(p0, c, lo, hi, radius, grow_lo, grow_hi) -> bool:  # pragma: no cover - compiled
    """Whether some box meets conv({p0} ∪ B(c, radius)) = ∪_t B(p0 + t (c - p0), t radius). The gap
    dist(point(t), box) - t radius is convex in t, so a golden-section search finds its minimum;
    boxes whose slab test grown by ``radius`` misses are skipped (``grow_*``: scratch (3,))."""
    g = 0.5 * (np.sqrt(5.0) - 1.0)
    d0, d1, d2 = c[0] - p0[0], c[1] - p0[1], c[2] - p0[2]
    for j in range(lo.shape[0]):
        for a in range(3):
            grow_lo[a] = lo[j, a] - radius
            grow_hi[a] = hi[j, a] + radius
        if not _hits(p0[0], p0[1], p0[2], d0, d1, d2, grow_lo, grow_hi):
            continue
        a_, b_ = 0.0, 1.0
        c_ = b_ - g * (b_ - a_)
        e_ = a_ + g * (b_ - a_)
        fc = _cone_gap(p0, d0, d1, d2, c_, lo[j], hi[j], radius)
        fe = _cone_gap(p0, d0, d1, d2, e_, lo[j], hi[j], radius)
        for _ in range(48):
            if fc < fe:
                b_, e_, fe = e_, c_, fc
                c_ = b_ - g * (b_ - a_)
                fc = _cone_gap(p0, d0, d1, d2, c_, lo[j], hi[j], radius)
            else:
                a_, c_, fc = c_, e_, fe
                e_ = a_ + g * (b_ - a_)
                fe = _cone_gap(p0, d0, d1, d2, e_, lo[j], hi[j], radius)
        best = min(
            fc,
            fe,
            _cone_gap(p0, d0, d1, d2, 0.0, lo[j], hi[j], radius),
            _cone_gap(p0, d0, d1, d2, 1.0, lo[j], hi[j], radius),
        )
        if best < 0.0:
            return True
    return False


@numba.njit(cache=True)
def cone_box_blocked_any(apex, centre, lo, hi, radius):  # pragma: no cover - compiled
    """True where some box meets the sight cone from ``apex[i]`` to the ball B(centre[i], radius)."""
    n = apex.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    grow_lo = np.empty(3)
    grow_hi = np.empty(3)
    for i in range(n):
        out[i] = _cone_blocked(apex[i], centre[i], lo, hi, radius, grow_lo, grow_hi)
    return out


@numba.njit(cache=True)
def hull_screen(points, reach, lo, hi):  # pragma: no cover - compiled
    """(K, m): for each node k, min over its samples ``points[k]`` (K, P, 3) of the distance to box
    j (0 inside), minus ``reach[k]``. Bit for bit ``lookback.min_box_distance_all(points.reshape(
    -1, 3), lo, hi).reshape(K, P, m).min(axis=1) - reach[:, None]`` (the same clip, differences,
    squares summed in axis order and square root), without its (K P, m, 3) temporaries."""
    K, P, m = points.shape[0], points.shape[1], lo.shape[0]
    out = np.empty((K, m))
    for k in range(K):
        for j in range(m):
            best = np.inf
            for p in range(P):
                s = 0.0
                for a in range(3):
                    x = points[k, p, a]
                    q = min(max(x, lo[j, a]), hi[j, a])
                    d = x - q
                    s += d * d
                dist = np.sqrt(s)
                if dist < best:
                    best = dist
            out[k, j] = best - reach[k]
    return out


@numba.njit(cache=True)
def polyline_distances(p, q):  # pragma: no cover - compiled
    """Distance from each point ``p`` (n, 3) to the polyline through ``q`` (m >= 2, 3): per point
    the least distance to a segment ``q[j] -> q[j + 1]``, the nearest point on it at the clipped
    projection (a zero-length segment: its vertex). :func:`polytope.polyline_distance`'s loop,
    without its (points x segments x 3) temporaries."""
    n, s = p.shape[0], q.shape[0] - 1
    d = q[1:] - q[:-1]  # (s, 3) segment directions, and their squared lengths (1 if zero)
    dd = np.empty(s)
    for j in range(s):
        sq = d[j, 0] * d[j, 0] + d[j, 1] * d[j, 1] + d[j, 2] * d[j, 2]
        dd[j] = sq if sq > 0.0 else 1.0
    out = np.empty(n)
    for i in range(n):
        best = np.inf
        for j in range(s):
            d0, d1, d2 = d[j, 0], d[j, 1], d[j, 2]
            r0, r1, r2 = p[i, 0] - q[j, 0], p[i, 1] - q[j, 1], p[i, 2] - q[j, 2]
            t = (r0 * d0 + r1 * d1 + r2 * d2) / dd[j]
            t = min(max(t, 0.0), 1.0)
            g0, g1, g2 = r0 - t * d0, r1 - t * d1, r2 - t * d2
            best = min(best, g0 * g0 + g1 * g1 + g2 * g2)
        out[i] = np.sqrt(best)
    return out
