"""The true obstacles of a scenario: what the simulator collides with and ray-casts (the robot's
planner never sees them). Re-exported by :mod:`secure3d.world.attacks`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from secure3d.world.octomap_files import octomap_voxel_boxes
from secure3d.world.spec import Box, MeshObstacle, Scenario

__all__ = ["TrueObstacles", "true_obstacles"]


@dataclass(frozen=True, eq=False)
class TrueObstacles:
    """Every true obstacle, in the form the simulator's collision and camera modules take.

    Attributes
    ----------
    boxes : tuple of Box
    meshes : tuple of MeshObstacle
    voxel_boxes : (n, 2, 3) float
        ``[lo, hi]`` of the occupied leaves of ``world.octomap`` (empty without one).
    """

    boxes: tuple[Box, ...]
    meshes: tuple[MeshObstacle, ...]
    voxel_boxes: np.ndarray

    def aabbs(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds of every obstacle (meshes by their bounding box).

        Returns
        -------
        lo, hi : (k, 3) float
            Boxes, then meshes, then voxels.
        """
        parts_lo = [np.array([o.lo for o in (*self.boxes, *self.meshes)]).reshape(-1, 3)]
        parts_hi = [np.array([o.hi for o in (*self.boxes, *self.meshes)]).reshape(-1, 3)]
        parts_lo.append(self.voxel_boxes[:, 0])
        parts_hi.append(self.voxel_boxes[:, 1])
        return np.concatenate(parts_lo), np.concatenate(parts_hi)


def true_obstacles(scenario: Scenario) -> TrueObstacles:
    """Every true obstacle: named boxes and meshes plus the occupied voxels of ``world.octomap``."""
    w = scenario.world
    voxels = (
        np.zeros((0, 2, 3))
        if w.octomap is None
        else octomap_voxel_boxes(w.octomap, "world.octomap")
    )
    return TrueObstacles(w.boxes, w.meshes, voxels)
