"""Compiled bounding-volume hierarchy over axis-aligned boxes, and its exact queries.

The tree (:func:`build`) is a binary BVH: every node's bounds are the exact min / max of the
corners of the boxes below it (no arithmetic, so no rounding), which makes every pruning test below
*exact*: a test that fails for a node's bounds fails for every box below it, because each test is
monotone in the box's corners in floating point too (correctly rounded subtraction, division,
products and square roots are monotone). So every query returns bit for bit what the brute-force
loops of :mod:`secure3d.geometry._box_kernels` return over all boxes (tests check this on random
maps); the tree only skips boxes that cannot change the answer.

Tree arrays (``N`` nodes, ``m`` boxes):

- ``perm`` (m,) int64: box indices in leaf order; a leaf holds ``perm[start : start + count]``;
- ``nlo``, ``nhi`` (N, 3) float: node bounds;
- ``child`` (N,) int64: index of the first child (the second is ``child + 1``), -1 for a leaf;
- ``start``, ``count`` (N,) int64: the leaf's range in ``perm`` (count 0 for inner nodes).
"""

from __future__ import annotations

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.geometry._box_kernels import _cone_gap, _hits, _point_box_distance

#: Boxes per leaf: small leaves prune more, large ones walk fewer nodes.
LEAF_SIZE = 4
#: Depth of the traversal stack (the build splits by halves at worst: depth <= 2 log2(m) + 2).
_STACK = 256


@numba.njit(cache=True)
def _node_bounds(lo, hi, perm, s, e, out_lo, out_hi, node):  # pragma: no cover - compiled
    for a in range(3):
        out_lo[node, a] = np.inf
        out_hi[node, a] = -np.inf
    for k in range(s, e):
        j = perm[k]
        for a in range(3):
            if lo[j, a] < out_lo[node, a]:
                out_lo[node, a] = lo[j, a]
            if hi[j, a] > out_hi[node, a]:
                out_hi[node, a] = hi[j, a]


@numba.njit(cache=True)
def _split(lo, hi, perm, s, e):  # pragma: no cover - compiled
    """Partition perm[s:e] at the middle of the box centres' extent along its longest axis; the
    middle index if one side would be empty (coincident centres)."""
    cmin = np.full(3, np.inf)
    cmax = np.full(3, -np.inf)
    for k in range(s, e):
        j = perm[k]
        for a in range(3):
            c = lo[j, a] + hi[j, a]
            cmin[a] = min(cmin[a], c)
            cmax[a] = max(cmax[a], c)
    axis = int(np.argmax(cmax - cmin))
    mid = 0.5 * (cmin[axis] + cmax[axis])
    i, k = s, e - 1
    while i <= k:
        if lo[perm[i], axis] + hi[perm[i], axis] < mid:
            i += 1
        else:
            perm[i], perm[k] = perm[k], perm[i]
            k -= 1
    if i == s or i == e:
        i = (s + e) // 2
    return i


@numba.njit(cache=True)
def build(lo, hi, leaf_size):  # pragma: no cover - compiled
    """The tree over boxes (lo, hi) (m, 3): (perm, nlo, nhi, child, start, count); see the module."""
    m = lo.shape[0]
    cap = max(1, 2 * m)
    perm = np.arange(m)
    nlo = np.empty((cap, 3))
    nhi = np.empty((cap, 3))
    child = np.full(cap, -1, dtype=np.int64)
    start = np.zeros(cap, dtype=np.int64)
    count = np.zeros(cap, dtype=np.int64)
    n_nodes = 1
    stack = np.empty((cap, 4), dtype=np.int64)  # (node, s, e, depth)
    stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3] = 0, 0, m, 0
    top = 1
    while top > 0:
        top -= 1
        node, s, e, depth = stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3]
        _node_bounds(lo, hi, perm, s, e, nlo, nhi, node)
        if e - s <= leaf_size:
            start[node], count[node] = s, e - s
            continue
        # past depth 64, halves by index: depth stays <= 64 + log2(m) < _STACK
        mid = _split(lo, hi, perm, s, e) if depth < 64 else (s + e) // 2
        child[node] = n_nodes
        stack[top, 0], stack[top, 1], stack[top, 2], stack[top, 3] = n_nodes, s, mid, depth + 1
        stack[top + 1, 0], stack[top + 1, 1] = n_nodes + 1, mid
        stack[top + 1, 2], stack[top + 1, 3] = e, depth + 1
        top += 2
        n_nodes += 2
    return (
        perm,
        nlo[:n_nodes].copy(),
        nhi[:n_nodes].copy(),
        child[:n_nodes].copy(),
        start[:n_nodes].copy(),
        count[:n_nodes].copy(),
    )


@numba.njit(cache=True, inline="always")
def _signed(x, y, z, lo, hi) -> float:  # pragma: no cover - compiled
    """Signed distance from (x, y, z) to the box [lo, hi], the expression of
    ``_box_kernels.min_signed_distance`` exactly (so both give the same bits)."""
    out2 = 0.0
    inside = -np.inf
    for axis in range(3):
        p = x if axis == 0 else (y if axis == 1 else z)
        q = max(lo[axis] - p, p - hi[axis])
        if q > 0.0:
            out2 += q * q
        if q > inside:
            inside = q
    return np.sqrt(out2) if out2 > 0.0 else min(inside, 0.0)


@numba.njit(cache=True)
def min_signed_distance(
    points, upper, lo, hi, perm, nlo, nhi, child, start, count
):  # pragma: no cover
    """(n,) min(upper[i], smallest signed distance from points[i] to any box): branch and bound,
    nearer child first, a node skipped when its bounds' signed distance (a lower bound for every
    box below) is >= the best so far.

    The search for a point starts from its distance to the box nearest the previous point (when a
    box was nearer than that point's cap): one of the candidates, so the minimum is unchanged bit
    for bit, but along a grid row or a path it is already (nearly) the answer and prunes most of
    the tree from the first node on."""
    n = points.shape[0]
    out = upper.copy()
    stack = np.empty(_STACK, dtype=np.int64)
    bound = np.empty(_STACK)  # each stacked node's lower bound, computed when it was pushed
    if lo.shape[0] == 0:
        return out
    prev = -1  # the box nearest the last point that had one nearer than its cap
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        best = out[i]
        arg = -1
        if prev >= 0:
            d = _signed(x, y, z, lo[prev], hi[prev])
            if d < best:
                best, arg = d, prev
        stack[0] = 0
        bound[0] = _signed(x, y, z, nlo[0], nhi[0])
        top = 1
        while top > 0:
            top -= 1
            node = stack[top]
            if bound[top] >= best:
                continue
            c = child[node]
            if c < 0:
                for k in range(start[node], start[node] + count[node]):
                    d = _signed(x, y, z, lo[perm[k]], hi[perm[k]])
                    if d < best:
                        best, arg = d, perm[k]
                continue
            da = _signed(x, y, z, nlo[c], nhi[c])
            db = _signed(x, y, z, nlo[c + 1], nhi[c + 1])
            if da <= db:  # push the nearer last: it is visited first
                stack[top], bound[top], stack[top + 1], bound[top + 1] = c + 1, db, c, da
            else:
                stack[top], bound[top], stack[top + 1], bound[top + 1] = c, da, c + 1, db
            top += 2
        out[i] = best
        if arg >= 0:
            prev = arg
    return out


@numba.njit(cache=True)
def _segment_touches(
    a0, a1, a2, d0, d1, d2, lo, hi, perm, nlo, nhi, child, start, count, stack
):  # pragma: no cover - compiled
    """Whether the segment from (a0, a1, a2) along (d0, d1, d2) touches some closed box (the slab
    test of ``_box_kernels.segment_box_any``, nodes whose bounds it misses skipped). ``stack``
    (_STACK,) int64 is scratch."""
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        if not _hits(a0, a1, a2, d0, d1, d2, nlo[node], nhi[node]):
            continue
        c = child[node]
        if c >= 0:
            stack[top], stack[top + 1] = c, c + 1
            top += 2
            continue
        for k in range(start[node], start[node] + count[node]):
            if _hits(a0, a1, a2, d0, d1, d2, lo[perm[k]], hi[perm[k]]):
                return True
    return False


@numba.njit(cache=True)
def segment_any(p0, p1, lo, hi, perm, nlo, nhi, child, start, count):  # pragma: no cover
    """(n,) whether segment [p0[i], p1[i]] touches some closed box."""
    n = p0.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    stack = np.empty(_STACK, dtype=np.int64)
    if lo.shape[0] == 0:
        return out
    for i in range(n):
        a0, a1, a2 = p0[i, 0], p0[i, 1], p0[i, 2]
        d0, d1, d2 = p1[i, 0] - a0, p1[i, 1] - a1, p1[i, 2] - a2
        out[i] = _segment_touches(
            a0, a1, a2, d0, d1, d2, lo, hi, perm, nlo, nhi, child, start, count, stack
        )
    return out


@numba.njit(cache=True)
def fans_clear(
    origins, tips, indptr, cols, lo, hi, perm, nlo, nhi, child, start, count
):  # pragma: no cover - compiled
    """(r,) whether, for row i, some origin ``origins[cols[k]]``, k in ``indptr[i]:indptr[i+1]``
    (tried in that order, stopping at the first), sees every point ``tips[i, t]``: no segment from
    it to them touches a box (each segment the test of :func:`segment_any`)."""
    r = tips.shape[0]
    out = np.zeros(r, dtype=np.bool_)
    stack = np.empty(_STACK, dtype=np.int64)
    for i in range(r):
        for k in range(indptr[i], indptr[i + 1]):
            o = cols[k]
            a0, a1, a2 = origins[o, 0], origins[o, 1], origins[o, 2]
            clear = True
            for t in range(tips.shape[1]):
                d0, d1, d2 = tips[i, t, 0] - a0, tips[i, t, 1] - a1, tips[i, t, 2] - a2
                if lo.shape[0] > 0 and _segment_touches(
                    a0, a1, a2, d0, d1, d2, lo, hi, perm, nlo, nhi, child, start, count, stack
                ):
                    clear = False
                    break
            if clear:
                out[i] = True
                break
    return out


@numba.njit(cache=True)
def _cone_box_gap(p0, d0, d1, d2, blo, bhi, radius) -> float:  # pragma: no cover - compiled
    """Smallest gap dist(p0 + t d, box) - t radius over t in [0, 1]: the golden-section search of
    ``_box_kernels._cone_blocked``, step for step."""
    g = 0.5 * (np.sqrt(5.0) - 1.0)
    a_, b_ = 0.0, 1.0
    c_ = b_ - g * (b_ - a_)
    e_ = a_ + g * (b_ - a_)
    fc = _cone_gap(p0, d0, d1, d2, c_, blo, bhi, radius)
    fe = _cone_gap(p0, d0, d1, d2, e_, blo, bhi, radius)
    for _ in range(48):
        if fc < fe:
            b_, e_, fe = e_, c_, fc
            c_ = b_ - g * (b_ - a_)
            fc = _cone_gap(p0, d0, d1, d2, c_, blo, bhi, radius)
        else:
            a_, c_, fc = c_, e_, fe
            e_ = a_ + g * (b_ - a_)
            fe = _cone_gap(p0, d0, d1, d2, e_, blo, bhi, radius)
    return min(
        fc,
        fe,
        _cone_gap(p0, d0, d1, d2, 0.0, blo, bhi, radius),
        _cone_gap(p0, d0, d1, d2, 1.0, blo, bhi, radius),
    )


@numba.njit(cache=True)
def cone_blocked(  # pragma: no cover - compiled
    p0, c, radius, lo, hi, perm, nlo, nhi, child, start, count, stack, glo, ghi
):
    """Whether some box meets conv({p0} ∪ B(c, radius)); nodes and boxes whose bounds grown by
    ``radius`` the segment p0 -> c misses are skipped (as ``_box_kernels._cone_blocked`` skips
    boxes). ``stack`` (_STACK,) int64 and ``glo``, ``ghi`` (3,) are scratch."""
    if lo.shape[0] == 0:
        return False
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
            j = perm[k]
            for a in range(3):
                glo[a] = lo[j, a] - radius
                ghi[a] = hi[j, a] + radius
            if not _hits(p0[0], p0[1], p0[2], d0, d1, d2, glo, ghi):
                continue
            if _cone_box_gap(p0, d0, d1, d2, lo[j], hi[j], radius) < 0.0:
                return True
    return False


@numba.njit(cache=True)
def cones_blocked(  # pragma: no cover - compiled
    apex, centre, radius, lo, hi, perm, nlo, nhi, child, start, count
):
    """(n,) :func:`cone_blocked` for each (apex[i], centre[i])."""
    n = apex.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    stack = np.empty(_STACK, dtype=np.int64)
    glo = np.empty(3)
    ghi = np.empty(3)
    for i in range(n):
        out[i] = cone_blocked(
            apex[i], centre[i], radius, lo, hi, perm, nlo, nhi, child, start, count, stack, glo, ghi
        )
    return out


@numba.njit(cache=True)
def near_mask(points, radius, lo, hi, perm, nlo, nhi, child, start, count):  # pragma: no cover
    """(m,) bool: boxes within distance radius[i] (closed) of some points[i]; unsigned distance
    (0 inside), the expression of ``_box_kernels._point_box_distance``."""
    m = lo.shape[0]
    out = np.zeros(m, dtype=np.bool_)
    stack = np.empty(_STACK, dtype=np.int64)
    if m == 0:
        return out
    for i in range(points.shape[0]):
        x, y, z, r = points[i, 0], points[i, 1], points[i, 2], radius[i]
        stack[0] = 0
        top = 1
        while top > 0:
            top -= 1
            node = stack[top]
            if _point_box_distance(x, y, z, nlo[node], nhi[node]) > r:
                continue
            c = child[node]
            if c >= 0:
                stack[top], stack[top + 1] = c, c + 1
                top += 2
                continue
            for k in range(start[node], start[node] + count[node]):
                j = perm[k]
                if _point_box_distance(x, y, z, lo[j], hi[j]) <= r:
                    out[j] = True
    return out


@numba.njit(cache=True)
def overlap_mask(a, b, lo, hi, perm, nlo, nhi, child, start, count):  # pragma: no cover - compiled
    """(m,) bool: boxes that overlap the closed box [a, b] (3,), ``lo <= b`` and ``hi >= a`` on
    every axis (comparisons only: exact). A node whose bounds fail the test has no box below it
    that passes (its bounds are its boxes' extreme corners)."""
    m = lo.shape[0]
    out = np.zeros(m, dtype=np.bool_)
    if m == 0:
        return out
    stack = np.empty(_STACK, dtype=np.int64)
    stack[0] = 0
    top = 1
    while top > 0:
        top -= 1
        node = stack[top]
        miss = False
        for d in range(3):
            if nlo[node, d] > b[d] or nhi[node, d] < a[d]:
                miss = True
        if miss:
            continue
        c = child[node]
        if c >= 0:
            stack[top], stack[top + 1] = c, c + 1
            top += 2
            continue
        for k in range(start[node], start[node] + count[node]):
            j = perm[k]
            if (
                lo[j, 0] <= b[0]
                and lo[j, 1] <= b[1]
                and lo[j, 2] <= b[2]
                and hi[j, 0] >= a[0]
                and hi[j, 1] >= a[1]
                and hi[j, 2] >= a[2]
            ):
                out[j] = True
    return out
