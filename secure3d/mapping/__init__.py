"""secure3d.mapping: OctoMap-compatible occupancy store with trust layers (sensor vs server claim).

- :class:`OccupancyMap` — sensor log-odds with OctoMap's exact semantics, the server's claim kept
  apart, known-obstacle queries, merged boxes and surface meshes for the planner, ``.bt``/``.ot``
  files;
- :class:`OccupancyParams`, :class:`InsertStats`, :class:`Trust`;
- :func:`depth_image_points` — a pinhole z-depth image as world points (Open3D's pixel convention).

See ``secure3d/mapping/occupancy.py`` for the update rules (DESIGN.md section 4).
"""

from secure3d.mapping.occupancy import (
    InsertStats,
    OccupancyMap,
    OccupancyParams,
    Trust,
    depth_image_points,
)

__all__ = ["InsertStats", "OccupancyMap", "OccupancyParams", "Trust", "depth_image_points"]
