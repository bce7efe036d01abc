"""What a planner reads of an :class:`~secure3d.mapping.occupancy.OccupancyMap`: the known
obstacles as axis-aligned boxes (all of them, or those near a corridor) and as a closed surface."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from secure3d.errors import ConfigError, GeometryError
from secure3d.mapping.boxes import boxes_near_points
from secure3d.mapping.keys import TREE_MAX_VAL, check_points, morton_decode
from secure3d.mapping.obstacle_boxes import obstacle_boxes
from secure3d.mapping.surface import boundary_mesh
from secure3d.validation import is_int_in

__all__ = ["ObstacleViews"]

MAX_BOX_CACHE = 4  # merged box sets kept per map content (one per option combination asked)


class ObstacleViews:
    """The planner views of :class:`~secure3d.mapping.occupancy.OccupancyMap` (a mixin: it reads
    the map's ``_known_obstacle_codes``, ``_sensor_voxels``, ``_claim``, ``_params``,
    ``_resolution``, ``_bounds`` and caches boxes in ``_box_cache``, a dict the map's copies share
    until one changes)."""

    def known_obstacle_boxes(
        self, max_boxes: int | None = None, include_bounds: bool = True, close_gaps: int = 0
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Known obstacle voxels merged into axis-aligned boxes (cached until the map changes).

        Parameters
        ----------
        max_boxes : int or None
            Budget; if the exact cover needs more boxes, a conservative coarser cover is returned
            (a superset of the obstacles, see :func:`secure3d.mapping.boxes.merge_cells_budget`).
        include_bounds : bool
            With ``bounds`` set, add six slabs (as thick as the bounds' largest extent) around
            them, so "outside is unplannable" reaches the planner as obstacles.
        close_gaps : int
            Morphological closing radius (voxels) applied before merging: gaps up to ``2 *
            close_gaps`` voxels wide between obstacle voxels are filled. Sensed surfaces come as
            combs of hit voxels separated by carved ones; closing them gives a planner a few solid
            boxes instead of hundreds of slivers. Only ever adds obstacles (conservative), at the
            price of closing openings narrower than the gap.

        Returns
        -------
        lo, hi : (m, 3) float64
            Box corners (m).
        """
        if not is_int_in(close_gaps, 0):
            raise ConfigError(f"close_gaps: must be an integer >= 0, got {close_gaps!r}")
        key = (max_boxes, include_bounds, close_gaps)
        cached = self._box_cache.get(key)
        if cached is not None:
            return cached[0].copy(), cached[1].copy()
        lo, hi = obstacle_boxes(
            self._known_obstacle_codes(),
            self._resolution,
            self._bounds if include_bounds else None,
            max_boxes,
            close_gaps,
        )
        if len(self._box_cache) >= MAX_BOX_CACHE:
            self._box_cache.pop(next(iter(self._box_cache)))
        self._box_cache[key] = (lo, hi)
        return lo.copy(), hi.copy()

    def boxes_near(
        self, points: ArrayLike, radius: float, max_boxes: int | None = None
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Known obstacle boxes within ``radius`` of any of ``points`` (a corridor).

        Parameters
        ----------
        points : (k, 3) float
        radius : float
            Distance (m) from the points; boxes touching that neighbourhood are returned.
        max_boxes : int or None
            Passed to :meth:`known_obstacle_boxes`.

        Returns
        -------
        lo, hi : (m, 3) float64
        """
        p = check_points(points)
        if not np.all(np.isfinite(p)):
            raise GeometryError("boxes_near: points must be finite")
        if not (isinstance(radius, (int, float, np.integer, np.floating)) and radius >= 0.0):
            raise GeometryError(f"boxes_near: radius must be a number >= 0, got {radius!r}")
        lo, hi = self.known_obstacle_boxes(max_boxes)
        near = boxes_near_points(lo, hi, p, float(radius))
        return lo[near], hi[near]

    def surface_mesh(self, which: str = "known") -> tuple[NDArray[np.float64], NDArray[np.int64]]:
        """Closed outer surface of a voxel set (faces between set and non-set voxels).

        Parameters
        ----------
        which : {"known", "sensed", "claimed"}
            Known obstacles, sensed occupied voxels, or claimed occupied voxels.

        Returns
        -------
        vertices : (v, 3) float64
            Voxel corners (m).
        faces : (f, 3) int64
            Triangles, counter-clockwise seen from outside.
        """
        if which == "known":
            codes = self._known_obstacle_codes()
        elif which == "sensed":
            codes, vals = self._sensor_voxels()
            codes = codes[vals >= self._params.threshold_log]
        elif which == "claimed":
            codes = self._claim.occupied_codes()
        else:
            raise ConfigError(f"surface_mesh: which must be known/sensed/claimed, got {which!r}")
        corners, faces = boundary_mesh(morton_decode(codes))
        return (corners - TREE_MAX_VAL).astype(np.float64) * self._resolution, faces
