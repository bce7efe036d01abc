"""The edges of a 26-connected grid graph over its free cells, in compressed sparse row order.

:func:`secure3d.planning.guess.grid_route` searches such a graph with scipy's Dijkstra. Building it
with numpy (26 sliced index arrays, masked, concatenated, a COO matrix converted to CSR) took
0.10-0.13 s of a forest guess's 0.27 s (the route 0.13 s); this kernel lists the same edges in one
pass, already in the order of a canonical CSR matrix, so the graph (and the route) is the same bit
for bit, and the route takes 0.08 s.
"""

from __future__ import annotations

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)


@numba.njit(cache=True)
def grid_edges(
    free: np.ndarray, shape: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Edges between free cells of a grid, row by row of the adjacency matrix.

    Parameters
    ----------
    free : (N,) bool, the cells (flat, C order) of a grid of shape ``shape`` (3,) int64.
    offsets : (k, 3) int64 neighbour offsets in {-1, 0, 1}, in increasing order of their flat
        step (so a row's destinations come out sorted).

    Returns
    -------
    indptr : (N + 1,) int32, row starts (CSR; scipy's graph routines take int32 indices).
    src, dst : (E,) int32, each edge's cells, by source cell then offset.
    kind : (E,) int8, each edge's row in ``offsets``.
    """
    n0, n1, n2 = shape[0], shape[1], shape[2]
    steps = offsets[:, 0] * (n1 * n2) + offsets[:, 1] * n2 + offsets[:, 2]
    room = np.count_nonzero(free) * offsets.shape[0]
    indptr = np.zeros(free.shape[0] + 1, np.int32)
    src = np.empty(room, np.int32)
    dst = np.empty(room, np.int32)
    kind = np.empty(room, np.int8)
    e = 0
    c = 0
    for i in range(n0):
        for j in range(n1):
            for k in range(n2):
                if free[c]:
                    for o in range(offsets.shape[0]):
                        a = i + offsets[o, 0]
                        b = j + offsets[o, 1]
                        d = k + offsets[o, 2]
                        if a < 0 or a >= n0 or b < 0 or b >= n1 or d < 0 or d >= n2:
                            continue
                        t = c + steps[o]
                        if free[t]:
                            src[e] = c
                            dst[e] = t
                            kind[e] = o
                            e += 1
                c += 1
                indptr[c] = e
    return indptr, src[:e], dst[:e], kind[:e]


# ---- Dijkstra over the grid's implicit graph ---------------------------------------------------
#
# scipy's ``dijkstra`` on the graph of :func:`grid_edges` costs a CSR matrix of every edge (26 per
# free cell) and a search of every reachable cell; :func:`grid_search` walks the same graph without
# building it and stops once the goal's cell is settled. A 26-connected grid has many routes of
# equal cost (staircases), so which one comes out depends on the order in which cells are settled.
# scipy (1.15 and later) serves the smallest distance first and, among equal distances, the highest
# cell index (a queue of (-distance, cell) pairs), and changes a cell's predecessor only when its
# distance strictly falls. The heap here (one entry per cell, moved up when its distance falls)
# settles cells in that order too, so the route is scipy's, ties included.

_SETTLED = -2


@numba.njit(cache=True, inline="always")
def _sift_down(key: np.ndarray, cell: np.ndarray, pos: np.ndarray, size: int) -> None:
    """Put the heap's last entry (slot ``size``) at its place from the root down."""
    k, c = key[size], cell[size]
    i = 0
    while True:
        m = 2 * i + 1
        if m >= size:
            break
        r = m + 1
        if r < size and (key[r] < key[m] or (key[r] == key[m] and cell[r] > cell[m])):
            m = r
        if not (key[m] < k or (key[m] == k and cell[m] > c)):
            break
        key[i] = key[m]
        cell[i] = cell[m]
        pos[cell[i]] = i
        i = m
    key[i] = k
    cell[i] = c
    pos[c] = i


@numba.njit(cache=True, inline="always")
def _sift_up(key: np.ndarray, cell: np.ndarray, pos: np.ndarray, i: int, k: float, c: int) -> None:
    """Put entry (k, c) at its place from slot ``i`` up."""
    while i > 0:
        up = (i - 1) >> 1
        if not (k < key[up] or (k == key[up] and c > cell[up])):
            break
        key[i], cell[i] = key[up], cell[up]
        pos[cell[i]] = i
        i = up
    key[i], cell[i] = k, c
    pos[c] = i


@numba.njit(cache=True)
def grid_search(
    free: np.ndarray,
    shape: np.ndarray,
    offsets: np.ndarray,
    lengths: np.ndarray,
    weight: np.ndarray,
    source: int,
    target: int,
) -> tuple[np.ndarray, float]:
    """The cheapest route between two cells of the graph of :func:`grid_edges`, by Dijkstra.

    Parameters
    ----------
    free, shape, offsets : as :func:`grid_edges` (no edge leaves or enters a cell that is not free).
    lengths : (k,) float, the length of a step along each offset.
    weight : (N,) float > 0, a cost per metre of each cell; a step from cell ``a`` to ``b`` along
        offset ``o`` costs ``lengths[o] * max(weight[a], weight[b])``.
    source, target : flat cells.

    Returns
    -------
    cells : (n,) int64, the route's cells from ``source`` to ``target`` (empty: none joins them).
    cost : its cost (inf if none): the distance scipy's ``dijkstra`` gives on the graph of
        :func:`grid_edges` with those weights, and the route its predecessors give.
    """
    n1, n2 = shape[1], shape[2]
    n = shape[0] * n1 * n2
    steps = offsets[:, 0] * (n1 * n2) + offsets[:, 1] * n2 + offsets[:, 2]
    best = np.full(n, np.inf)
    pred = np.full(n, -1, np.int64)
    pos = np.full(n, -1, np.int64)  # a cell's heap slot; -1: not reached; _SETTLED
    key = np.full(n, np.inf)
    cell = np.full(n, -1, np.int64)
    best[source] = 0.0
    _sift_up(key, cell, pos, 0, 0.0, source)
    size = 1
    while size > 0:
        d, v = key[0], cell[0]
        pos[v] = _SETTLED
        size -= 1
        if size > 0:
            _sift_down(key, cell, pos, size)
        if v == target:
            break
        if not free[v]:
            continue  # the graph has no edges from a cell that is not free
        i, rest = v // (n1 * n2), v % (n1 * n2)
        j, k = rest // n2, rest % n2
        wv = weight[v]
        for o in range(offsets.shape[0]):
            a, b, c = i + offsets[o, 0], j + offsets[o, 1], k + offsets[o, 2]
            if a < 0 or a >= shape[0] or b < 0 or b >= n1 or c < 0 or c >= n2:
                continue
            t = v + steps[o]
            if not free[t] or pos[t] == _SETTLED:
                continue
            wt = weight[t]
            nxt = d + lengths[o] * (wv if wv >= wt else wt)  # max(): the same float
            if best[t] > nxt:
                best[t] = nxt
                pred[t] = v
                slot = pos[t]
                if slot < 0:  # a new entry, else the entry moves up
                    slot = size
                    size += 1
                _sift_up(key, cell, pos, slot, nxt, t)
    if pos[target] != _SETTLED:
        return np.zeros(0, np.int64), np.inf
    m = 1
    c = target
    while c != source:
        c = pred[c]
        m += 1
    cells = np.empty(m, np.int64)
    c = target
    for q in range(m - 1, -1, -1):
        cells[q] = c
        c = pred[c]
    return cells, best[target]
