"""Sticky hits: the planner's safety layer, in which a voxel the camera hit stays an obstacle.

OctoMap's log-odds layer (kept bit-identical for ``.bt`` interop) lowers a voxel's occupancy with
every ray that passes through it without ending in it. For an obstacle thinner than a voxel, rays
that graze past it through the voxel's free part carve the voxel free from far away, and near by
it takes several hits (+0.85 each from the clamp at -2.0) before the voxel is occupied again:
measured on a 4 cm pole with 0.1 m voxels, three frames, by which time a fast robot cannot stop.

The rule kept here (DESIGN.md section 7, "A hit is not carved free"): **a voxel with a sensed hit
is a known obstacle from its first hit on, and no later evidence clears it.** Why never:

- the threat model's world is static; only the server's map is adversarial. A hit proves that
  some surface lies in the voxel (up to the depth noise along the ray). A later ray through the
  voxel that does not end in it proves only that *its own line* is free, and no finite set of lines
  proves that a whole voxel is free (a wire thinner than the gaps between them survives any such
  set). The only evidence that could soundly clear a hit is "the surface moved", which a static
  world rules out;
- the server never clears a sensed hit (its claim is the lowest trust), and a sensed hit never
  clears anything in the claim: a moved-obstacle attack (the server deletes an obstacle and invents
  one elsewhere) leaves every hit standing;
- the price is liveness, not safety: a spurious hit (depth noise near a surface) stays a small
  phantom obstacle next to the real one.

The layer is a sorted array of Morton codes (the codes of :mod:`secure3d.mapping.keys`); it only
grows, by the ``occupied`` voxels of every scan.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from secure3d.mapping.keys import unique_sorted


class HitLayer:
    """The set of voxels with at least one sensed hit (sorted, distinct Morton codes)."""

    __slots__ = ("_codes",)

    def __init__(self, codes: ArrayLike | None = None) -> None:
        self._codes = (
            np.empty(0, np.int64) if codes is None else unique_sorted(np.asarray(codes, np.int64))
        )

    def __len__(self) -> int:
        return int(self._codes.size)

    @property
    def codes(self) -> NDArray[np.int64]:
        """The hit voxels' Morton codes, ``(n,) int64`` sorted (a read-only view)."""
        view = self._codes.view()
        view.flags.writeable = False
        return view

    def add(self, codes: ArrayLike) -> int:
        """Record hits; returns how many voxels are new to the layer.

        Parameters
        ----------
        codes : (k,) int64
            Morton codes of voxels a scan marked occupied (any order, repeats allowed).
        """
        new = np.asarray(codes, dtype=np.int64).ravel()
        if not new.size:
            return 0
        new = unique_sorted(new)
        fresh = new[~self.contains(new)]
        if fresh.size:
            # the union of two sorted runs: timsort merges them in linear time
            self._codes = np.sort(np.concatenate([self._codes, fresh]), kind="stable")
        return int(fresh.size)

    def contains(self, codes: ArrayLike) -> NDArray[np.bool_]:
        """Whether each voxel has been hit, ``(k,) bool`` for ``(k,) int64`` codes (``-1``: no)."""
        c = np.asarray(codes, dtype=np.int64)
        if not self._codes.size:
            return np.zeros(c.shape, bool)
        pos = np.minimum(np.searchsorted(self._codes, c), self._codes.size - 1)
        return (self._codes[pos] == c) & (c >= 0)

    def copy(self) -> HitLayer:
        out = HitLayer()
        out._codes = self._codes.copy()
        return out
