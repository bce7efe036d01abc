"""OctoMap voxel keys, Morton codes and the batched 3D DDA that turns a scan into voxel updates.

Everything here reproduces OctoMap 1.9/1.10 bit for bit (DESIGN.md section 5), in three modules
this one gathers (their names stay importable from here):

- :mod:`secure3d.mapping.morton`, key arithmetic: a coordinate is first rounded to ``float32``
  (OctoMap's ``point3d``), then ``key = floor(c * (1/res)) + 32768`` in double precision; keys
  live in ``[0, 65536)`` (16 levels); voxels are identified by 48-bit Morton codes whose sorted
  order is the octree's depth-first order;
- :mod:`secure3d.mapping.raycast`, one ray: its free keys come from OctoMap's ``computeRayKeys``
  (Amanatides & Woo DDA): the origin voxel is included, the end voxel excluded, with the same
  float/double mix (so ties break the same way);
- :mod:`secure3d.mapping.scan`, a whole scan (``computeUpdate``): every ray voxel is marked free
  and every endpoint occupied, each voxel once per scan, occupied winning over free; a beam
  longer than ``max_range`` only clears space up to ``max_range`` along its direction and marks
  nothing occupied (``clear_range`` may shorten that, for sensors whose range limit is not a
  sphere); ``discretize`` reproduces ``computeDiscreteUpdate``.
"""

from __future__ import annotations

from secure3d.mapping.morton import (
    KEY_LIMIT,
    TREE_DEPTH,
    TREE_MAX_VAL,
    box_codes,
    box_keys,
    codes_to_coords,
    coords_to_codes,
    coords_to_keys,
    keys_to_coords,
    morton_decode,
    morton_encode,
    tile_voxel_count,
    tiles_to_codes,
    unique_sorted,
)
from secure3d.mapping.raycast import check_origin, check_points, ray_keys
from secure3d.mapping.scan import ScanTiles, ScanUpdate, scan_tiles, scan_update

__all__ = [
    "KEY_LIMIT",
    "TREE_DEPTH",
    "TREE_MAX_VAL",
    "ScanTiles",
    "ScanUpdate",
    "box_codes",
    "box_keys",
    "check_origin",
    "check_points",
    "codes_to_coords",
    "coords_to_codes",
    "coords_to_keys",
    "keys_to_coords",
    "morton_decode",
    "morton_encode",
    "ray_keys",
    "scan_tiles",
    "scan_update",
    "tile_voxel_count",
    "tiles_to_codes",
    "unique_sorted",
]
