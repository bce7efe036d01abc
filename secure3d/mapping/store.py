"""Storage of per-voxel log-odds: a numba hash table of finest-level voxels plus coarse leaves.

A sensor-built map only has finest-level voxels (depth 16), kept in an open-addressing hash table
(``int64`` Morton code -> ``float32`` log-odds) so that a scan's updates and point queries are O(1)
per voxel inside numba kernels. A map read from a ``.bt``/``.ot`` file may also hold *coarse
leaves*: pruned octree nodes at depth < 16 that stand for ``8**(16 - depth)`` voxels with one value.
They are kept as they are (a sorted array of Morton ranges), which bounds memory by the file size,
and split exactly like OctoMap's ``expandNode`` (one level at a time, 8 children carrying the
parent's value) when an update touches them. Queries give the same answer either way.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import GeometryError
from secure3d.mapping.keys import TREE_DEPTH

_EMPTY = -1
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
#: Largest number of voxels a coarse-leaf expansion may produce (about 1 GB of centres). Asking
#: for more (e.g. every free voxel of a huge pruned ``.bt``) raises instead of exhausting memory.
MAX_EXPANDED_VOXELS = 40_000_000


@numba.njit(cache=True, inline="always")
def _slot(key: int, shift: int) -> int:
    return np.int64((np.uint64(key) * _GOLDEN) >> np.uint64(shift))


@numba.njit(cache=True)
def _lookup(keys: np.ndarray, shift: int, codes: np.ndarray) -> np.ndarray:
    """Slot of each code in the table, or -1 (codes of -1 stand for invalid points)."""
    mask = keys.shape[0] - 1
    out = np.empty(codes.shape[0], np.int64)
    for i in range(codes.shape[0]):
        c = codes[i]
        out[i] = -1
        if c < 0:
            continue
        h = _slot(c, shift)
        while True:
            k = keys[h]
            if k == c:
                out[i] = h
                break
            if k == _EMPTY:
                break
            h = (h + 1) & mask
    return out


@numba.njit(cache=True)
def _insert_slots(keys: np.ndarray, shift: int, codes: np.ndarray) -> tuple[np.ndarray, int]:
    """Slots of ``codes``, inserting missing ones (capacity must suffice); returns (slots, new)."""
    mask = keys.shape[0] - 1
    out = np.empty(codes.shape[0], np.int64)
    new = 0
    for i in range(codes.shape[0]):
        c = codes[i]
        h = _slot(c, shift)
        while True:
            k = keys[h]
            if k == c:
                break
            if k == _EMPTY:
                keys[h] = c
                new += 1
                break
            h = (h + 1) & mask
        out[i] = h
    return out, new


@numba.njit(cache=True)
def _add_logodds(
    keys: np.ndarray,
    vals: np.ndarray,
    shift: int,
    codes: np.ndarray,
    start: int,
    room: int,
    delta: np.float32,
    clamp_min: np.float32,
    clamp_max: np.float32,
) -> tuple[int, int]:
    """OctoMap's ``updateNodeLogOdds`` for ``codes[start:]`` (new voxels start at 0), stopping
    before the code that would be the ``room + 1``-th new entry; returns (where it stopped, #new).

    Arithmetic is float32 like OctoMap's nodes: ``v += delta`` then clamp to [min, max].
    """
    mask = keys.shape[0] - 1
    new = 0
    for i in range(start, codes.shape[0]):
        c = codes[i]
        h = _slot(c, shift)
        while True:
            k = keys[h]
            if k == c:
                v = vals[h] + delta
                break
            if k == _EMPTY:
                if new == room:
                    return i, new
                keys[h] = c
                new += 1
                v = np.float32(0.0) + delta
                break
            h = (h + 1) & mask
        if v < clamp_min:
            v = clamp_min
        elif v > clamp_max:
            v = clamp_max
        vals[h] = v
    return codes.shape[0], new


@numba.njit(cache=True)
def _rehash(
    keys: np.ndarray, vals: np.ndarray, new_cap: int, shift: int
) -> tuple[np.ndarray, np.ndarray]:
    nk = np.full(new_cap, _EMPTY, np.int64)
    nv = np.empty(new_cap, np.float32)
    mask = new_cap - 1
    for i in range(keys.shape[0]):
        c = keys[i]
        if c != _EMPTY:
            h = _slot(c, shift)
            while nk[h] != _EMPTY:
                h = (h + 1) & mask
            nk[h] = c
            nv[h] = vals[i]
    return nk, nv


class VoxelTable:
    """Hash table from finest-level Morton code (``int64``) to a ``float32`` value.

    Linear probing with Fibonacci hashing, load factor at most 1/2, no deletion (OctoMap never
    deletes voxels on update either).
    """

    def __init__(self, capacity: int = 1 << 12) -> None:
        cap = 1 << max(4, int(np.ceil(np.log2(max(capacity, 16)))))
        self.keys = np.full(cap, _EMPTY, np.int64)
        self.vals = np.zeros(cap, np.float32)
        self.count = 0

    @property
    def _shift(self) -> int:
        return 64 - int(self.keys.shape[0]).bit_length() + 1

    def reserve(self, extra: int) -> None:
        """Grow so that ``extra`` more entries keep the load factor at most 1/2."""
        need = 2 * (self.count + int(extra))
        cap = self.keys.shape[0]
        if need <= cap:
            return
        while cap < need:
            cap *= 2
        self.keys, self.vals = _rehash(self.keys, self.vals, cap, 64 - cap.bit_length() + 1)

    def _room(self) -> int:
        """New entries the table takes before its load factor exceeds 1/2."""
        return max(0, self.keys.shape[0] // 2 - self.count)

    def slots(self, codes: NDArray[np.int64]) -> NDArray[np.int64]:
        """Slot of each code, ``-1`` if absent (or if the code is negative)."""
        return _lookup(self.keys, self._shift, np.ascontiguousarray(codes, dtype=np.int64))

    def get(self, codes: NDArray[np.int64]) -> NDArray[np.float32]:
        """Values of ``codes``; NaN where absent."""
        s = self.slots(codes)
        out = np.full(s.shape[0], np.nan, np.float32)
        hit = s >= 0
        out[hit] = self.vals[s[hit]]
        return out

    def set(self, codes: NDArray[np.int64], values: NDArray[np.float32]) -> None:
        """Insert or overwrite; ``codes`` must be unique."""
        codes = np.ascontiguousarray(codes, dtype=np.int64)
        self.reserve(codes.shape[0])
        s, new = _insert_slots(self.keys, self._shift, codes)
        self.vals[s] = values
        self.count += int(new)

    def add_logodds(
        self, codes: NDArray[np.int64], delta: float, clamp_min: float, clamp_max: float
    ) -> None:
        """Add ``delta`` to each (unique) code's log-odds, creating at 0, clamping (float32)."""
        codes = np.ascontiguousarray(codes, dtype=np.int64)
        # Grow only when the entries actually added need it, not whenever len(codes) might: most
        # codes of a scan are already in the table (a 2 cm map, 6M codes a frame, 0.4-1M of them
        # new, held 33M voxels in 134M slots when every call reserved room for all its codes).
        done = 0
        while True:
            done, new = _add_logodds(
                self.keys,
                self.vals,
                self._shift,
                codes,
                done,
                self._room(),
                np.float32(delta),
                np.float32(clamp_min),
                np.float32(clamp_max),
            )
            self.count += int(new)
            if done == codes.shape[0]:
                return
            # out of room: grow as if every remaining code were new (one rehash for a fresh map)
            self.reserve(codes.shape[0] - done)

    def items(self) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        """All (codes, values), sorted by code (depth-first octree order)."""
        used = self.keys != _EMPTY
        codes = self.keys[used]
        vals = self.vals[used]
        order = np.argsort(codes, kind="stable")
        return codes[order], vals[order]

    def copy(self) -> VoxelTable:
        out = VoxelTable.__new__(VoxelTable)
        out.keys = self.keys.copy()
        out.vals = self.vals.copy()
        out.count = self.count
        return out


def leaf_span(depth: NDArray[np.integer]) -> NDArray[np.int64]:
    """Number of finest voxels (= Morton range length) of a leaf at each depth, ``8**(16-d)``."""
    return np.left_shift(np.int64(1), 3 * (TREE_DEPTH - np.asarray(depth, dtype=np.int64)))


def expand_ranges(
    starts: NDArray[np.int64], depths: NDArray[np.integer], limit: int = MAX_EXPANDED_VOXELS
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Finest-level codes covered by coarse leaves, and the leaf index of each.

    Raises
    ------
    GeometryError
        If the expansion would exceed ``limit`` voxels.
    """
    spans = leaf_span(depths)
    total = int(spans.sum()) if spans.size else 0
    if total > limit:
        raise GeometryError(
            f"expanding {spans.size} pruned leaves would create {total} voxels (limit {limit}); "
            "use OccupancyMap.leaves() for the pruned form"
        )
    owner = np.repeat(np.arange(spans.size), spans)
    first = np.cumsum(spans) - spans
    codes = starts[owner] + (np.arange(total, dtype=np.int64) - first[owner])
    return codes, owner


class LeafLayer:
    """Log-odds of every known voxel: finest voxels in a :class:`VoxelTable` plus coarse leaves.

    Invariant: coarse leaves never overlap each other nor any finest voxel in the table.
    """

    def __init__(self) -> None:
        self.table = VoxelTable()
        self.c_start = np.empty(0, np.int64)
        self.c_depth = np.empty(0, np.int8)
        self.c_val = np.empty(0, np.float32)

    # ------------------------------------------------------------------ queries

    def __len__(self) -> int:
        """Number of finest-level voxels covered (coarse leaves count all their voxels)."""
        return self.table.count + int(leaf_span(self.c_depth).sum())

    def get(self, codes: NDArray[np.int64]) -> NDArray[np.float32]:
        """Log-odds at each finest code; NaN where unknown or the code is negative."""
        codes = np.ascontiguousarray(codes, dtype=np.int64)
        out = self.table.get(codes)
        if self.c_start.size:
            miss = np.flatnonzero(np.isnan(out) & (codes >= 0))
            idx, inside = self._locate(codes[miss])
            out[miss[inside]] = self.c_val[idx[inside]]
        return out

    def _locate(self, codes: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """Index of the coarse leaf containing each code, and whether one does."""
        idx = np.searchsorted(self.c_start, codes, side="right") - 1
        ok = idx >= 0
        idx_c = np.where(ok, idx, 0)
        inside = ok & (codes < self.c_start[idx_c] + leaf_span(self.c_depth[idx_c]))
        return idx_c, inside

    def leaves(self) -> tuple[NDArray[np.int64], NDArray[np.int8], NDArray[np.float32]]:
        """All leaves as (first finest code, depth, value), sorted by code."""
        codes, vals = self.table.items()
        if not self.c_start.size:
            return codes, np.full(codes.shape, TREE_DEPTH, np.int8), vals
        starts = np.concatenate([codes, self.c_start])
        depths = np.concatenate([np.full(codes.shape, TREE_DEPTH, np.int8), self.c_depth])
        values = np.concatenate([vals, self.c_val])
        order = np.argsort(starts, kind="stable")
        return starts[order], depths[order], values[order]

    def voxels(self, limit: int = MAX_EXPANDED_VOXELS) -> tuple[NDArray[np.int64], NDArray]:
        """All finest-level (codes, values), coarse leaves expanded, sorted by code."""
        codes, vals = self.table.items()
        if not self.c_start.size:
            return codes, vals
        ccodes, owner = expand_ranges(self.c_start, self.c_depth, limit - codes.size)
        codes = np.concatenate([codes, ccodes])
        vals = np.concatenate([vals, self.c_val[owner]])
        order = np.argsort(codes, kind="stable")
        return codes[order], vals[order]

    def voxels_at_least(
        self, threshold: float, limit: int = MAX_EXPANDED_VOXELS
    ) -> NDArray[np.int64]:
        """The finest-level codes whose value is >= ``threshold`` (coarse leaves expanded), sorted:
        ``codes[vals >= threshold]`` of :meth:`voxels` without sorting every voxel."""
        t = self.table
        codes = t.keys[(t.keys != _EMPTY) & (t.vals >= threshold)]
        if self.c_start.size:
            sel = self.c_val >= threshold
            ccodes, _ = expand_ranges(self.c_start[sel], self.c_depth[sel], limit - codes.size)
            codes = np.concatenate([codes, ccodes])
        return np.sort(codes)

    # ------------------------------------------------------------------ updates

    def add_logodds(
        self, codes: NDArray[np.int64], delta: float, clamp_min: float, clamp_max: float
    ) -> None:
        """OctoMap's per-voxel log-odds update for unique finest ``codes``."""
        if codes.size == 0:
            return
        self._split_coarse(codes)
        self.table.add_logodds(codes, delta, clamp_min, clamp_max)

    def set_leaves(
        self, starts: NDArray[np.int64], depths: NDArray[np.integer], values: NDArray[np.float32]
    ) -> None:
        """Replace the whole content with the given non-overlapping leaves."""
        depths = np.asarray(depths, dtype=np.int8)
        fine = depths == TREE_DEPTH
        self.table = VoxelTable(2 * int(fine.sum()))
        self.table.set(starts[fine], np.asarray(values, np.float32)[fine])
        order = np.argsort(starts[~fine], kind="stable")
        self.c_start = np.asarray(starts[~fine], np.int64)[order]
        self.c_depth = depths[~fine][order]
        self.c_val = np.asarray(values, np.float32)[~fine][order]

    def _split_coarse(self, codes: NDArray[np.int64]) -> None:
        """Expand every coarse leaf containing one of ``codes`` down to the finest level.

        Like OctoMap's ``expandNode`` along the update path: one level at a time, each split leaf
        becomes 8 children with its value, so untouched siblings stay coarse.
        """
        for _ in range(TREE_DEPTH):
            if not self.c_start.size:
                return
            idx, inside = self._locate(codes)
            if not inside.any():
                return
            hit = np.unique(idx[inside])
            keep = np.ones(self.c_start.size, bool)
            keep[hit] = False
            child_depth = (self.c_depth[hit].astype(np.int64) + 1)[:, None]
            child_start = self.c_start[hit][:, None] + np.arange(8) * leaf_span(child_depth)
            child_start = child_start.ravel()
            child_depth = np.broadcast_to(child_depth, (hit.size, 8)).ravel().astype(np.int8)
            child_val = np.repeat(self.c_val[hit], 8)
            fine = child_depth == TREE_DEPTH
            self.table.set(child_start[fine], child_val[fine])
            starts = np.concatenate([self.c_start[keep], child_start[~fine]])
            order = np.argsort(starts, kind="stable")
            self.c_start = starts[order]
            self.c_depth = np.concatenate([self.c_depth[keep], child_depth[~fine]])[order]
            self.c_val = np.concatenate([self.c_val[keep], child_val[~fine]])[order]

    def copy(self) -> LeafLayer:
        out = LeafLayer.__new__(LeafLayer)
        out.table = self.table.copy()
        out.c_start = self.c_start.copy()
        out.c_depth = self.c_depth.copy()
        out.c_val = self.c_val.copy()
        return out
