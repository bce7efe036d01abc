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

__all__ = ["hull_near"]


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
