"""secure3d.mapping: OctoMap-compatible occupancy store with trust layers (sensor vs server claim).

- :class:`OccupancyMap` — sensor log-odds with OctoMap's exact semantics, the server's claim kept
  apart, known-obstacle queries, merged boxes and surface meshes for the planner, ``.bt``/``.ot``
  files;
- :class:`OccupancyParams`, :class:`InsertStats`, :class:`Trust`.

See ``secure3d/mapping/occupancy.py`` for the update rules (DESIGN.md section 4).
"""

from secure3d.mapping.occupancy import InsertStats, OccupancyMap, OccupancyParams, Trust

__all__ = ["InsertStats", "OccupancyMap", "OccupancyParams", "Trust"]
