"""The entries of :func:`secure3d.geometry._box_kernels.hull_screen` at most a limit, through the
box index's tree instead of over every box.

``hull_screen(points, reach, lo, hi)[k, j]`` is the smallest distance from node k's samples
``points[k]`` to box j minus ``reach[k]``; the obstacle-slot selection and the check for missing
slots only use the entries up to a limit (the slot radius, the margin). The kernel here walks the
bounding-volume hierarchy of :mod:`~secure3d.geometry._box_index_kernels` once per node and skips a
tree node when the same expression over the node's bounds exceeds the limit: the bounds contain
every box below, the clip-difference-square-root expression is monotone in the box corners in
floating point too, and so is subtracting ``reach[k]``, so no skipped box has an entry within the
limit. The entries it returns are computed by hull_screen's own expression, bit for bit (tests
compare them on random boxes).
"""

from __future__ import annotations

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.geometry._box_index_kernels import _STACK

__all__ = ["hull_near", "hull_nearest"]


@numba.njit(cache=True, inline="always")
def _entry(points, k, lo, hi, reach) -> float:  # pragma: no cover - compiled
    """hull_screen's entry for node k and the box [lo, hi] (3,), the same operations in order."""
    best = np.inf
    for p in range(points.shape[1]):
        s = 0.0
        for a in range(3):
            x = points[k, p, a]
            q = min(max(x, lo[a]), hi[a])
            d = x - q
            s += d * d
        dist = np.sqrt(s)
        if dist < best:
            best = dist
    return best - reach


@numba.njit(cache=True)
def hull_near(
    points, reach, limit, lo, hi, perm, nlo, nhi, child, start, count
):  # pragma: no cover
    """Pairs (k, j) with ``hull_screen(points, reach, lo, hi)[k, j] <= limit`` and those entries:
    (k (n,), j (n,), value (n,)), by k, then j ascending."""
    K = points.shape[0]
    cap = 1024
    ks = np.empty(cap, np.int64)
    js = np.empty(cap, np.int64)
    vs = np.empty(cap)
    n = 0
    stack = np.empty(_STACK, np.int64)
    if lo.shape[0] == 0:
        return ks[:0], js[:0], vs[:0]
    for k in range(K):
        first = n
        stack[0] = 0
        top = 1
        while top > 0:
            top -= 1
            node = stack[top]
            if _entry(points, k, nlo[node], nhi[node], reach[k]) > limit:
                continue
            c = child[node]
            if c >= 0:
                stack[top], stack[top + 1] = c, c + 1
                top += 2
                continue
            for q in range(start[node], start[node] + count[node]):
                j = perm[q]
                v = _entry(points, k, lo[j], hi[j], reach[k])
                if v <= limit:
                    if n == cap:
                        cap *= 2
                        ks2 = np.empty(cap, np.int64)
                        js2 = np.empty(cap, np.int64)
                        vs2 = np.empty(cap)
                        for r in range(n):  # element-wise: no shape-mismatch formatting compiled
                            ks2[r], js2[r], vs2[r] = ks[r], js[r], vs[r]
                        ks, js, vs = ks2, js2, vs2
                    ks[n], js[n], vs[n] = k, j, v
                    n += 1
        order = np.argsort(js[first:n])
        js_k = js[first:n][order]
        vs_k = vs[first:n][order]
        for r in range(n - first):
            js[first + r] = js_k[r]
            vs[first + r] = vs_k[r]
    return ks[:n], js[:n], vs[:n]


@numba.njit(cache=True)
def hull_nearest(
    points, reach, limit, n, lo, hi, perm, nlo, nhi, child, start, count
):  # pragma: no cover
    """Per node k, ``n`` entries of row k of ``hull_screen(points, reach, lo, hi)`` that are the
    smallest and at most ``limit``: (k (r,), j (r,), value (r,)), by k, then value (then j)
    ascending; at most n per row. Their *values* are the row's n smallest within the limit
    whatever the ties; which of several boxes with equal entries is returned is not defined.
    Branch and bound, nearer child first: a tree node is skipped when its entry (a lower bound
    for every box below) exceeds the limit or is at least the largest of n entries kept."""
    K = points.shape[0]
    ks = np.empty(K * n, np.int64)
    js = np.empty(K * n, np.int64)
    vs = np.empty(K * n)
    r = 0
    stack = np.empty(_STACK, np.int64)
    bound = np.empty(_STACK)
    best_v = np.empty(n)
    best_j = np.empty(n, np.int64)
    if lo.shape[0] == 0 or n == 0:
        return ks[:0], js[:0], vs[:0]
    for k in range(K):
        kept = 0
        worst = 0  # position of the largest kept entry (when kept == n)
        stack[0] = 0
        bound[0] = _entry(points, k, nlo[0], nhi[0], reach[k])
        top = 1
        while top > 0:
            top -= 1
            node = stack[top]
            b = bound[top]
            if b > limit or (kept == n and b >= best_v[worst]):
                continue
            c = child[node]
            if c >= 0:
                da = _entry(points, k, nlo[c], nhi[c], reach[k])
                db = _entry(points, k, nlo[c + 1], nhi[c + 1], reach[k])
                if da <= db:  # push the nearer last: it is visited first
                    stack[top], bound[top], stack[top + 1], bound[top + 1] = c + 1, db, c, da
                else:
                    stack[top], bound[top], stack[top + 1], bound[top + 1] = c, da, c + 1, db
                top += 2
                continue
            for q in range(start[node], start[node] + count[node]):
                j = perm[q]
                v = _entry(points, k, lo[j], hi[j], reach[k])
                if v > limit:
                    continue
                if kept < n:
                    best_v[kept], best_j[kept] = v, j
                    kept += 1
                elif v < best_v[worst]:
                    best_v[worst], best_j[worst] = v, j
                else:
                    continue
                if kept == n:
                    worst = 0
                    for t in range(1, n):
                        if best_v[t] > best_v[worst]:
                            worst = t
        # this row's entries, by value then box
        for t in range(1, kept):
            v, j = best_v[t], best_j[t]
            u = t - 1
            while u >= 0 and (best_v[u] > v or (best_v[u] == v and best_j[u] > j)):
                best_v[u + 1], best_j[u + 1] = best_v[u], best_j[u]
                u -= 1
            best_v[u + 1], best_j[u + 1] = v, j
        for t in range(kept):
            ks[r], js[r], vs[r] = k, best_j[t], best_v[t]
            r += 1
    return ks[:r], js[:r], vs[:r]
