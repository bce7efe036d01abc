"""The server's claim on an :class:`~secure3d.mapping.occupancy.OccupancyMap`: recording it.

The claim layer itself (:class:`~secure3d.mapping.claim.ClaimLayer`) holds the claimed voxels;
these are the map's methods that turn voxels, boxes, meshes or another map into claims. New claims
override older ones on the same voxel; sensor evidence overrides every claim when the map is read.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from secure3d.errors import ConfigError, GeometryError
from secure3d.mapping.claim import MAX_CLAIM_VOXELS, box_claim_codes, mesh_claim_codes
from secure3d.mapping.keys import check_points

__all__ = ["ClaimEditing"]


class ClaimEditing:
    """The claim-editing methods of :class:`~secure3d.mapping.occupancy.OccupancyMap` (a mixin:
    it reads the map's ``_claim``, ``_sensor``, ``_resolution``, ``_codes`` and ``_changed``)."""

    def _merge_claims(self, codes: NDArray[np.int64], occupied: NDArray[np.bool_]) -> None:
        """New claims override older ones on the same voxel."""
        self._claim.merge(codes, occupied)
        self._changed()

    def set_claim_voxels(self, centres: ArrayLike, occupied: bool | ArrayLike = True) -> None:
        """Record the server's claim for the voxels containing ``centres``.

        Parameters
        ----------
        centres : (n, 3) float
            Points (m), typically voxel centres; each names the voxel containing it.
        occupied : bool or (n,) bool
            Claimed occupied (True) or free (False), per point or for all.

        Raises
        ------
        GeometryError
            Non-finite points or points outside the key range (the count is in the message).
        """
        codes, valid = self._codes(centres)
        if not valid.all():
            raise GeometryError(
                f"set_claim_voxels: {int((~valid).sum())} of {valid.size} points are non-finite "
                "or outside the key range"
            )
        occ = np.broadcast_to(np.asarray(occupied, dtype=bool), codes.shape)
        # The last claim of a voxel within one call wins, like later calls.
        rev_codes, rev_first = np.unique(codes[::-1], return_index=True)
        self._merge_claims(rev_codes, occ[::-1][rev_first])

    def set_claim_boxes(self, lo: ArrayLike, hi: ArrayLike, occupied: bool = True) -> None:
        """Claim axis-aligned boxes occupied or free.

        An occupied claim covers every voxel overlapping the box (conservative for obstacles); a
        free claim covers only voxels entirely inside it (conservative for free space).

        Parameters
        ----------
        lo, hi : (n, 3) float
            Box corners (m), ``lo <= hi``.
        occupied : bool
        """
        lo_a = check_points(lo, "lo")
        hi_a = check_points(hi, "hi")
        if lo_a.shape != hi_a.shape:
            raise GeometryError(f"lo and hi: shapes differ, {lo_a.shape} vs {hi_a.shape}")
        if not np.all(np.isfinite(lo_a) & np.isfinite(hi_a)) or np.any(hi_a < lo_a):
            raise GeometryError("set_claim_boxes: boxes must be finite with lo <= hi")
        codes = box_claim_codes(lo_a, hi_a, self._resolution, occupied)
        self._merge_claims(codes, np.full(len(codes), bool(occupied)))

    def set_claim_mesh(self, vertices: ArrayLike, faces: ArrayLike, occupied: bool = True) -> None:
        """Claim the interior of a closed triangle mesh occupied or free.

        Voxel centres are classified with Open3D's signed distance (negative inside, by ray
        parity). An occupied claim takes every voxel whose centre is inside or within half a
        voxel diagonal of the surface (so every voxel the solid touches); a free claim only voxels
        entirely inside (centre deeper than half a diagonal).

        Parameters
        ----------
        vertices : (v, 3) float
        faces : (f, 3) int
            A closed (watertight) mesh, any orientation.
        occupied : bool
        """
        verts = check_points(vertices, "vertices")
        tri = np.asarray(faces)
        if tri.ndim != 2 or tri.shape[1] != 3 or tri.shape[0] == 0:
            raise GeometryError(f"faces: expected (f, 3) indices, got shape {tri.shape}")
        if not np.all(np.isfinite(verts)) or tri.min() < 0 or tri.max() >= verts.shape[0]:
            raise GeometryError("set_claim_mesh: non-finite vertices or face index out of range")
        codes = mesh_claim_codes(verts, tri, self._resolution, occupied)
        self._merge_claims(codes, np.full(len(codes), bool(occupied)))

    def set_claim_from_map(self, other: ClaimEditing) -> None:
        """Take another map's sensor layer (e.g. a ``.bt`` from the server) as the claim.

        Its occupied voxels become claimed occupied, its free voxels claimed free; earlier claims on
        the same voxels are overridden.

        Raises
        ------
        ConfigError
            The resolutions differ.
        """
        if not isinstance(other, ClaimEditing):
            raise ConfigError(f"set_claim_from_map: expected OccupancyMap, got {type(other)}")
        if other.resolution != self._resolution:
            raise ConfigError(
                f"set_claim_from_map: resolution {other.resolution} differs from this map's "
                f"{self._resolution}"
            )
        codes, vals = other._sensor.voxels(MAX_CLAIM_VOXELS)
        self._merge_claims(codes, vals >= other.params.threshold_log)

    def clear_claim(self) -> None:
        """Forget everything the server claimed."""
        self._claim.clear()
        self._changed()
