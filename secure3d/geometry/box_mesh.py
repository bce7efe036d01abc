"""Many axis-aligned boxes as one triangle soup (pure array functions)."""

from __future__ import annotations

import numpy as np
import trimesh

__all__ = ["UNIT_BOX", "box_arrays"]

#: Unit cube centred at the origin (8 vertices, 12 outward-wound triangles), taken from trimesh so
#: every box mesh has the same winding as ``trimesh.creation.box``.
UNIT_BOX = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
_UNIT_BOX_VERTICES = np.asarray(UNIT_BOX.vertices, dtype=float)
_UNIT_BOX_FACES = np.asarray(UNIT_BOX.faces, dtype=np.int64)


def box_arrays(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of many axis-aligned boxes at once.

    Parameters
    ----------
    lo, hi : (n, 3) float
        Box corners.

    Returns
    -------
    vertices : (8 n, 3) float
    faces : (12 n, 3) int64
        Faces of box ``k`` are rows ``12 k .. 12 k + 11``, wound outwards.
    """
    lo = np.asarray(lo, dtype=float).reshape(-1, 3)
    hi = np.asarray(hi, dtype=float).reshape(-1, 3)
    centre, extent = 0.5 * (lo + hi), hi - lo
    vertices = centre[:, None, :] + _UNIT_BOX_VERTICES[None, :, :] * extent[:, None, :]
    faces = _UNIT_BOX_FACES[None, :, :] + 8 * np.arange(len(lo))[:, None, None]
    return vertices.reshape(-1, 3), faces.reshape(-1, 3)
