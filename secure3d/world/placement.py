"""Start and goal clear of the file-backed obstacles (meshes, the true world's OctoMap voxels).

:class:`~secure3d.world.spec.Scenario` checks start and goal against its boxes when it is built;
meshes and OctoMap voxels live in files, so :func:`check_start_goal_clear` runs once they are
loaded (:func:`secure3d.world.scenario.load_scenario`). Without it a start inside a wall was
accepted and the flight reported "collided at t=0.01 s".
"""

from __future__ import annotations

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.world.spec import MeshObstacle, Scenario, box_distance

__all__ = ["check_start_goal_clear", "point_mesh_distance", "winding_number"]


def winding_number(p: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> float:
    """Generalised winding number of the closed mesh around ``p`` (1 inside, 0 outside).

    Sum of the triangles' signed solid angles seen from ``p`` over 4 pi (Van Oosterom and
    Strackee); exact for a closed, consistently wound mesh.

    Parameters
    ----------
    p : (3,) float.
    vertices : (n, 3) float; faces : (m, 3) int, counter-clockwise seen from outside.
    """
    tri = vertices[faces] - np.asarray(p, float)  # (m, 3, 3)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = (
        la * lb * lc
        + np.einsum("ij,ij->i", a, b) * lc
        + np.einsum("ij,ij->i", a, c) * lb
        + np.einsum("ij,ij->i", b, c) * la
    )
    return float(np.sum(2.0 * np.arctan2(num, den)) / (4.0 * np.pi))


def point_mesh_distance(p: np.ndarray, vertices: np.ndarray, faces: np.ndarray) -> float:
    """Distance (m) from ``p`` (3,) to the surface of the mesh (its nearest triangle)."""
    from trimesh.triangles import closest_point

    tri = vertices[faces]
    q = closest_point(tri, np.repeat(np.asarray(p, float)[None], len(tri), axis=0))
    return float(np.min(np.linalg.norm(q - p, axis=1)))


def _mesh_overlap(p: np.ndarray, r: float, mesh: MeshObstacle) -> bool:
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    if np.any(p < lo - r) or np.any(p > hi + r):
        return False
    inside = winding_number(p, mesh.vertices, mesh.faces) > 0.5
    return inside or point_mesh_distance(p, mesh.vertices, mesh.faces) < r


def check_start_goal_clear(scenario: Scenario, voxel_boxes: np.ndarray | None) -> None:
    """Raise :class:`ScenarioError` if the body at the start or the goal overlaps a mesh or a voxel.

    Parameters
    ----------
    scenario : the scenario (its meshes loaded).
    voxel_boxes : (n, 2, 3) float ``[lo, hi]`` of the true world's occupied OctoMap leaves, or None.
    """
    r = scenario.vehicle.body_radius
    for what, pos in (("start", scenario.start.position), ("goal", scenario.goal.position)):
        p = np.asarray(pos, dtype=float)
        for mesh in scenario.world.meshes:
            if _mesh_overlap(p, r, mesh):
                raise ScenarioError(
                    f"{what}.position: the body (radius {r:g} m) overlaps mesh {mesh.name!r}"
                    f" (got {tuple(float(x) for x in p)})"
                )
        if voxel_boxes is not None and len(voxel_boxes):
            d = box_distance(voxel_boxes[:, 0], voxel_boxes[:, 1], p, p)
            if np.any(d < r):
                k = int(np.argmin(d))
                raise ScenarioError(
                    f"{what}.position: the body (radius {r:g} m) overlaps an occupied voxel of"
                    f" world.octomap at {tuple(float(x) for x in voxel_boxes[k, 0])}"
                    f" (got {tuple(float(x) for x in p)})"
                )
