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
from secure3d.geometry._box_index_kernels import _STACK, cone_blocked

#: Cameras found by repeated maximum scans before a point's remaining cameras are sorted instead.
_SCANS = 16


@numba.njit(cache=True)
def best_clear_views(  # pragma: no cover - compiled
    points, owner, R, o, sin_h, cos_h, sin_v, cos_v, far, far_range, radius, lo, hi, tree, tol, top
):
    """For each ball B(points[i], radius) and the cameras (R, o) of samples 0 .. owner[i] - 1:

    - ``raw[i]``: the best view margin min(horizontal side, vertical side, far) - radius;
    - ``found[i]``, ``best[i]``: the best margin among cameras whose sight cone is clear of the boxes
      (lo, hi) (their spatial index ``tree``: :attr:`BoxIndex.tree`, exact), trying cameras by decreasing margin and giving up past the ``top`` best once margins
      are <= -tol (then no camera can pass);
    - ``view[i]``: that camera (-1 if none was found).

    Margins are -inf where no earlier camera exists.
    """
    n, c = points.shape[0], R.shape[0]
    found = np.zeros(n, dtype=np.bool_)
    best = np.full(n, -np.inf)
    raw = np.full(n, -np.inf)
    view = np.full(n, -1, dtype=np.int64)
    m = np.empty(c)
    used = np.zeros(c, dtype=np.bool_)
    grow_lo = np.empty(3)
    grow_hi = np.empty(3)
    stack = np.empty(_STACK, dtype=np.int64)
    perm, nlo, nhi, child, start, count = tree
    for i in range(n):
        k = min(owner[i], c)
        if k <= 0:
            continue
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        top_margin = -np.inf
        for j in range(k):
            dx, dy, dz = px - o[j, 0], py - o[j, 1], pz - o[j, 2]
            # camera frame (x right, y down, z forward): R_j^T (p - o_j)
            x = R[j, 0, 0] * dx + R[j, 1, 0] * dy + R[j, 2, 0] * dz
            y = R[j, 0, 1] * dx + R[j, 1, 1] * dy + R[j, 2, 1] * dz
            z = R[j, 0, 2] * dx + R[j, 1, 2] * dy + R[j, 2, 2] * dz
            side_h = z * sin_h - abs(x) * cos_h
            side_v = z * sin_v - abs(y) * cos_v
            f = far - (np.sqrt(x * x + y * y + z * z) if far_range else z)
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
            if not cone_blocked(
                o[cam],
                points[i],
                radius,
                lo,
                hi,
                perm,
                nlo,
                nhi,
                child,
                start,
                count,
                stack,
                grow_lo,
                grow_hi,
            ):
                found[i] = True
                best[i] = cand
                view[i] = cam
                break
    return found, best, raw, view
