"""The claim layer: what the (untrusted) server says about each voxel, occupied or free.

:class:`~secure3d.mapping.occupancy.OccupancyMap` is a front over two layers (the split OctoMap
itself makes between a tree and what is stored in it): the sensor layer (our own evidence,
:mod:`secure3d.mapping.store`) and this one. Sensor evidence always overrides a claim; the front
applies that rule. Here: the claims themselves (sorted Morton codes and a flag each), how new claims
override old ones, and which voxels a claimed box or mesh covers.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from secure3d.errors import GeometryError
from secure3d.mapping.keys import KEY_LIMIT, TREE_MAX_VAL, box_codes, morton_encode, unique_sorted

__all__ = [
    "BOUNDARY_TOUCH",
    "MAX_CLAIM_VOXELS",
    "ClaimLayer",
    "box_cells",
    "box_claim_codes",
    "check_claim_size",
    "mesh_claim_codes",
]

#: Most voxels one claim call may create (about 0.5 GB); bigger claims are almost surely a unit or
#: resolution mistake.
MAX_CLAIM_VOXELS = 40_000_000
#: Fraction of a voxel within which a claimed box face counts as touching the neighbouring voxel.
BOUNDARY_TOUCH = 1e-3


class ClaimLayer:
    """The server's claims: ``codes`` (n,) int64 sorted unique Morton codes, ``occupied`` (n,)
    bool (claimed occupied, else claimed free)."""

    __slots__ = ("codes", "occupied")

    def __init__(self) -> None:
        self.codes = np.empty(0, np.int64)
        self.occupied = np.empty(0, bool)

    def __len__(self) -> int:
        return int(self.codes.size)

    def copy(self) -> ClaimLayer:
        out = ClaimLayer()
        out.codes, out.occupied = self.codes.copy(), self.occupied.copy()
        return out

    def state(self, codes: NDArray[np.int64]) -> NDArray[np.int8]:
        """-1 no claim, 0 claimed free, 1 claimed occupied, per code."""
        out = np.full(codes.shape, -1, np.int8)
        if self.codes.size:
            pos = np.searchsorted(self.codes, codes)
            pos_c = np.minimum(pos, self.codes.size - 1)
            hit = (self.codes[pos_c] == codes) & (codes >= 0)
            out[hit] = self.occupied[pos_c[hit]]
        return out

    def occupied_codes(self) -> NDArray[np.int64]:
        """Codes claimed occupied, sorted."""
        return self.codes[self.occupied]

    def merge(self, codes: NDArray[np.int64], occupied: NDArray[np.bool_]) -> None:
        """Add claims; new claims override older ones on the same voxel.

        Raises
        ------
        GeometryError
            The layer would hold more than :data:`MAX_CLAIM_VOXELS` voxels.
        """
        if (
            not self.codes.size
            and codes.size <= MAX_CLAIM_VOXELS
            and np.all(codes[1:] > codes[:-1])
        ):
            # the first claim, already sorted and distinct (the usual case): nothing to merge
            self.codes, self.occupied = codes, np.asarray(occupied, dtype=bool)
            return
        all_codes = np.concatenate([codes, self.codes])
        all_occ = np.concatenate([occupied, self.occupied])
        if all_codes.size > MAX_CLAIM_VOXELS:
            raise GeometryError(
                f"claim layer would hold {all_codes.size} voxels (limit {MAX_CLAIM_VOXELS}); "
                "check units and resolution"
            )
        self.codes, first = np.unique(all_codes, return_index=True)
        self.occupied = all_occ[first]

    def clear(self) -> None:
        self.codes = np.empty(0, np.int64)
        self.occupied = np.empty(0, bool)


def box_claim_codes(
    lo_a: NDArray[np.float64], hi_a: NDArray[np.float64], resolution: float, occupied: bool
) -> NDArray[np.int64]:
    """Sorted codes of the voxels a claim of the boxes ``[lo_a, hi_a]`` ((n, 3) float, checked)
    covers: an occupied claim every voxel overlapping a box, a free claim only voxels inside one."""
    a = lo_a / resolution
    b = hi_a / resolution
    if occupied:
        # A face lying exactly on a voxel boundary also claims the voxel in front of it: the
        # camera's hits on that face land on either side of the boundary (float rounding), and
        # an unclaimed sliver there would look like a new obstacle.
        first = np.floor(a - BOUNDARY_TOUCH).astype(np.int64)
        last = np.ceil(b + BOUNDARY_TOUCH).astype(np.int64) - 1
        last = np.maximum(last, first)  # a zero-thickness box still touches its voxel
    else:
        first = np.ceil(a).astype(np.int64)
        last = np.floor(b).astype(np.int64) - 1
    keys_lo = np.clip(first + TREE_MAX_VAL, 0, KEY_LIMIT - 1)
    keys_hi = np.clip(last + TREE_MAX_VAL, -1, KEY_LIMIT - 1)
    check_claim_size(keys_lo, keys_hi)
    codes = unique_sorted(box_codes(keys_lo, keys_hi))
    return codes


def mesh_claim_codes(
    verts: NDArray[np.float64], tri: NDArray, resolution: float, occupied: bool
) -> NDArray[np.int64]:
    """Sorted codes of the voxels a claim of a closed mesh (checked ``verts`` (v, 3), ``tri``
    (f, 3)) covers: occupied, every voxel the solid touches; free, voxels entirely inside."""
    from secure3d._deps import open3d

    half_diag = 0.5 * math.sqrt(3.0) * resolution
    lo = verts.min(axis=0) - half_diag
    hi = verts.max(axis=0) + half_diag
    klo = np.floor(lo / resolution).astype(np.int64) + TREE_MAX_VAL
    khi = np.floor(hi / resolution).astype(np.int64) + TREE_MAX_VAL
    keys = box_cells(np.clip(klo, 0, KEY_LIMIT - 1)[None], np.clip(khi, 0, KEY_LIMIT - 1)[None])
    centres = ((keys - TREE_MAX_VAL) + 0.5) * resolution
    o3d = open3d()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(verts.astype(np.float32)), o3d.core.Tensor(tri.astype(np.uint32))
    )
    sd = scene.compute_signed_distance(o3d.core.Tensor(centres.astype(np.float32))).numpy()
    take = sd <= half_diag if occupied else sd < -half_diag
    codes = unique_sorted(morton_encode(keys[take]))
    return codes


def check_claim_size(keys_lo: NDArray[np.int64], keys_hi: NDArray[np.int64]) -> None:
    total = int(np.prod(np.maximum(keys_hi - keys_lo + 1, 0), axis=1).sum())
    if total > MAX_CLAIM_VOXELS:
        raise GeometryError(
            f"boxes cover {total} voxels (limit {MAX_CLAIM_VOXELS}); check units and resolution"
        )


def box_cells(keys_lo: NDArray[np.int64], keys_hi: NDArray[np.int64]) -> NDArray[np.int64]:
    """All integer cells of inclusive boxes, ``(N, 3) int64`` (empty boxes contribute nothing)."""
    check_claim_size(keys_lo, keys_hi)
    ext = np.maximum(keys_hi - keys_lo + 1, 0)
    counts = np.prod(ext, axis=1)
    total = int(counts.sum())
    owner = np.repeat(np.arange(counts.size), counts)
    local = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)
    e = ext[owner]
    ix = local % e[:, 0]
    iy = (local // e[:, 0]) % e[:, 1]
    iz = local // (e[:, 0] * e[:, 1])
    return keys_lo[owner] + np.stack([ix, iy, iz], axis=1)
