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
