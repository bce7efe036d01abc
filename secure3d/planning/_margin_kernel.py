"""How far reactive ellipsoids lie inside earlier cameras' frusta, as one compiled loop (see
:func:`secure3d.planning.lookback.frustum_margins`).

The guess's visibility speed caps ask it of every pair (ellipsoid, earlier camera) along the guess,
about 70 x 70 pairs a call. The numpy form built (n, m, faces, 3) temporaries camera by camera
(30 ms a call on the warehouse); this loop evaluates the same sums in the same order.
"""

from __future__ import annotations

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)


@numba.njit(cache=True)
def earlier_frustum_margins(  # pragma: no cover - compiled
    A: np.ndarray, b: np.ndarray, C: np.ndarray, M: np.ndarray, first: np.ndarray
) -> np.ndarray:
    """(n, m) margin of ellipsoid i (centre C[i] (3,), shape M[i] (3, 3)) inside frustum j (faces
    A[j] (F, 3) . x <= b[j] (F,)): min over faces of b - (a . c + |M a|), for the pairs with
    i >= first[j]; -inf for the others. The support terms sum over their three products in index
    order, as the numpy form (einsum, then the norm of a 3-vector) does."""
    n, m, F = C.shape[0], A.shape[0], A.shape[1]
    out = np.full((n, m), -np.inf)
    for j in range(m):
        for i in range(first[j], n):
            worst = np.inf
            for f in range(F):
                a0, a1, a2 = A[j, f, 0], A[j, f, 1], A[j, f, 2]
                nc = a0 * C[i, 0] + a1 * C[i, 1] + a2 * C[i, 2]
                v0 = M[i, 0, 0] * a0 + M[i, 0, 1] * a1 + M[i, 0, 2] * a2
                v1 = M[i, 1, 0] * a0 + M[i, 1, 1] * a1 + M[i, 1, 2] * a2
                v2 = M[i, 2, 0] * a0 + M[i, 2, 1] * a1 + M[i, 2, 2] * a2
                gap = b[j, f] - (nc + np.sqrt(v0 * v0 + v1 * v1 + v2 * v2))
                if gap < worst:
                    worst = gap
            out[i, j] = worst
    return out
