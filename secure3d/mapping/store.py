"""Storage of per-voxel log-odds: a numba block table of finest-level voxels plus coarse leaves.

A sensor-built map only has finest-level voxels (depth 16). They are kept in blocks of 4 x 4 x 4
voxels, the voxels whose Morton codes share all bits but the low six: an open-addressing hash
table (``int64`` block code -> block number) over a ``float32`` array of whole blocks, NaN where a
voxel is unknown (the layout of voxblox's block maps). A scan's free voxels arrive as tiles, a
block code and a 64-bit mask each (:meth:`VoxelTable.add_logodds_tiles`): one hash probe per
block, and a whole block updated in one pass over 64 values side by side in memory; listed codes
(:meth:`VoxelTable.add_logodds`) share a probe while consecutive codes share a block. Measured on
the voxel updates of whole closed-loop flights (``forest``, 40 M updates; ``narrow_passage_20cm``
at 2 cm, 123 M): the blocks took 0.17-0.19x the time of the former table of single voxels
(Fibonacci hashing, one probe and one cache line per voxel) and 0.36x the memory; tiles take
0.45x and 0.73x the time of the same updates as codes (``benchmarks/results/map_store.md``). The
values are the same bit for bit either way.

A map read from a ``.bt``/``.ot`` file may also hold *coarse leaves*: pruned octree nodes at
depth < 16 that stand for ``8**(16 - depth)`` voxels with one value. They are kept as they are (a
sorted array of Morton ranges), which bounds memory by the file size, and split exactly like
OctoMap's ``expandNode`` (one level at a time, 8 children carrying the parent's value) when an
update touches them. Queries give the same answer either way.
"""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np
from numpy.typing import NDArray

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import GeometryError
from secure3d.mapping.morton import TILE_BITS, TREE_DEPTH, _ctz, _tile_masks, tiles_to_codes

_EMPTY = -1
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
#: Block codes per hash group (low bits of the code): 8 slots of 8 bytes, one cache line.
_GROUP_BITS = 3
_GROUP_MASK = (1 << _GROUP_BITS) - 1
#: Voxels of a block: the low BLOCK_BITS bits of a Morton code interleave the low two bits of x,
#: y and z, so a block is a 4 x 4 x 4 cube. (8 x 8 x 8 blocks were 10-30 % faster on dense scans
#: but cost 2 KB per isolated voxel; a 4 x 4 x 4 block costs 256 bytes.) A block is a tile of
#: :mod:`secure3d.mapping.morton`, the unit a scan's free voxels arrive in.
BLOCK_BITS = TILE_BITS
BLOCK = 1 << BLOCK_BITS
_INNER = BLOCK - 1
_FULL = np.uint64(0xFFFFFFFFFFFFFFFF)
#: Largest number of voxels a coarse-leaf expansion may produce (about 1 GB of centres). Asking
#: for more (e.g. every free voxel of a huge pruned ``.bt``) raises instead of exhausting memory.
MAX_EXPANDED_VOXELS = 40_000_000


@numba.njit(cache=True, inline="always")
def _probe(bkeys: np.ndarray, shift: int, bc: int) -> int:
    """Slot of block ``bc`` in the hash, or the empty slot where it would go.

    Blocks whose codes differ only in the low three bits (a 2 x 2 x 2 group of blocks, 8 x 8 x 8
    voxels) hash to the same aligned run of eight slots, each to its own slot in it: a scan's
    neighbouring tiles then probe the same cache line instead of eight scattered ones."""
    mask = bkeys.shape[0] - 1
    group = (np.uint64(bc >> _GROUP_BITS) * _GOLDEN) >> np.uint64(shift + _GROUP_BITS)
    h = np.int64((group << np.uint64(_GROUP_BITS)) | np.uint64(bc & _GROUP_MASK))
    while bkeys[h] != bc and bkeys[h] != _EMPTY:
        h = (h + 1) & mask
    return h


@numba.njit(cache=True)
def _lookup(
    bkeys: np.ndarray, bids: np.ndarray, shift: int, vals: np.ndarray, codes: np.ndarray
) -> np.ndarray:
    """Index into ``vals`` of each code's voxel, or -1 if unknown (or the code negative)."""
    out = np.full(codes.shape[0], -1, np.int64)
    last = -2
    base = -1
    for i in range(codes.shape[0]):
        c = codes[i]
        if c < 0:
            continue
        bc = c >> BLOCK_BITS
        if bc != last:
            h = _probe(bkeys, shift, bc)
            base = -1 if bkeys[h] == _EMPTY else np.int64(bids[h]) << BLOCK_BITS
            last = bc
        if base >= 0:
            j = base + (c & _INNER)
            if not np.isnan(vals[j]):
                out[i] = j
    return out


@numba.njit(cache=True)
def _update(
    bkeys: np.ndarray,
    bids: np.ndarray,
    shift: int,
    vals: np.ndarray,
    nblocks: int,
    codes: np.ndarray,
    start: int,
    values: np.ndarray,
    delta: np.float32,
    clamp_min: np.float32,
    clamp_max: np.float32,
) -> tuple[int, int, int]:
    """Update ``codes[start:]``, stopping before a code whose block does not fit; returns (where it
    stopped, blocks in use, voxels added).

    With ``values`` of the codes' length: store ``values[i]`` (overwrite). Else OctoMap's
    ``updateNodeLogOdds``, float32 like OctoMap's nodes: ``v += delta`` (new voxels start at 0),
    then clamp to [min, max].
    """
    room = bkeys.shape[0] // 2 - nblocks
    overwrite = values.shape[0] == codes.shape[0]
    new = 0
    last = -1
    base = 0
    for i in range(start, codes.shape[0]):
        c = codes[i]
        bc = c >> BLOCK_BITS
        if bc != last:
            h = _probe(bkeys, shift, bc)
            if bkeys[h] == _EMPTY:
                if room == 0:
                    return i, nblocks, new
                bkeys[h] = bc
                bids[h] = nblocks
                nblocks += 1
                room -= 1
            base = np.int64(bids[h]) << BLOCK_BITS
            last = bc
        j = base + (c & _INNER)
        v = vals[j]
        if np.isnan(v):
            new += 1
            v = np.float32(0.0)
        if overwrite:
            v = values[i]
        else:
            v = v + delta
            if v < clamp_min:
                v = clamp_min
            elif v > clamp_max:
                v = clamp_max
        vals[j] = v
    return codes.shape[0], nblocks, new


@numba.njit(cache=True)
def _update_tiles(
    bkeys: np.ndarray,
    bids: np.ndarray,
    shift: int,
    vals: np.ndarray,
    nblocks: int,
    blocks: np.ndarray,
    masks: np.ndarray,
    start: int,
    delta: np.float32,
    clamp_min: np.float32,
    clamp_max: np.float32,
) -> tuple[int, int, int]:
    """:func:`_update` (log-odds, not overwrite) of the voxels of tiles ``start:`` (block codes and
    masks, :mod:`secure3d.mapping.morton`'s tile form): one probe per tile, then its set bits.
    Returns (where it stopped, blocks in use, voxels added)."""
    room = bkeys.shape[0] // 2 - nblocks
    new = 0
    for i in range(start, blocks.shape[0]):
        h = _probe(bkeys, shift, blocks[i])
        if bkeys[h] == _EMPTY:
            if room == 0:
                return i, nblocks, new
            bkeys[h] = blocks[i]
            bids[h] = nblocks
            nblocks += 1
            room -= 1
        base = np.int64(bids[h]) << BLOCK_BITS
        m = masks[i]
        if m == _FULL:  # a whole block: one branch-free pass the compiler vectorises
            for j in range(base, base + BLOCK):
                v = vals[j]
                unknown = np.isnan(v)
                new += unknown
                v = np.float32(0.0) if unknown else v
                vals[j] = min(max(v + delta, clamp_min), clamp_max)
            continue
        while m:
            j = base + _ctz(m)
            m &= m - np.uint64(1)
            v = vals[j]
            if np.isnan(v):
                new += 1
                v = np.float32(0.0)
            vals[j] = min(max(v + delta, clamp_min), clamp_max)
    return blocks.shape[0], nblocks, new


@numba.njit(cache=True)
def _rehash(bkeys: np.ndarray, bids: np.ndarray, new_cap: int, shift: int) -> tuple:
    nk = np.full(new_cap, _EMPTY, np.int64)
    ni = np.zeros(new_cap, np.int32)
    for i in range(bkeys.shape[0]):
        if bkeys[i] != _EMPTY:
            h = _probe(nk, shift, bkeys[i])
            nk[h] = bkeys[i]
            ni[h] = bids[i]
    return nk, ni


class VoxelTable:
    """Map from finest-level Morton code (``int64``) to a ``float32`` value, in 4 x 4 x 4 blocks.

    The block hash uses linear probing with Fibonacci hashing at load factor at most 1/2; block
    storage holds as many blocks as half the hash's slots. No deletion (OctoMap never deletes
    voxels on update either); ``count`` is the number of voxels held.
    """

    def __init__(self, capacity: int = 1 << 12) -> None:
        """Room for ``capacity`` voxels packed in whole blocks (a sparse map grows as it needs)."""
        self._allocate(max(16, 2 * (int(capacity) >> BLOCK_BITS)))
        self.nblocks = 0
        self.count = 0

    def _allocate(self, slots: int) -> None:
        cap = 1 << max(4, int(np.ceil(np.log2(max(slots, 16)))))
        self.bkeys = np.full(cap, _EMPTY, np.int64)
        self.bids = np.zeros(cap, np.int32)
        self.vals = np.full((cap // 2) << BLOCK_BITS, np.nan, np.float32)

    @property
    def _shift(self) -> int:
        return 64 - int(self.bkeys.shape[0]).bit_length() + 1

    @property
    def capacity(self) -> int:
        """Blocks the table holds before it grows."""
        return self.bkeys.shape[0] // 2

    def reserve_blocks(self, extra: int) -> None:
        """Grow so that ``extra`` more blocks fit (hash load factor at most 1/2)."""
        need = 2 * (self.nblocks + int(extra))
        cap = self.bkeys.shape[0]
        if need <= cap:
            return
        while cap < need:
            cap *= 2
        self.bkeys, self.bids = _rehash(self.bkeys, self.bids, cap, 64 - cap.bit_length() + 1)
        vals = np.empty((cap // 2) << BLOCK_BITS, np.float32)
        n = self.vals.shape[0]
        vals[:n] = self.vals
        vals[n:] = np.nan
        self.vals = vals

    def _index(self, codes: NDArray[np.int64]) -> NDArray[np.int64]:
        """Index into the block storage of each code's voxel, ``-1`` if unknown or negative."""
        codes = np.ascontiguousarray(codes, dtype=np.int64)
        return _lookup(self.bkeys, self.bids, self._shift, self.vals, codes)

    def get(self, codes: NDArray[np.int64]) -> NDArray[np.float32]:
        """Values of ``codes``; NaN where absent."""
        s = self._index(codes)
        out = np.full(s.shape[0], np.nan, np.float32)
        hit = s >= 0
        out[hit] = self.vals[s[hit]]
        return out

    def _apply(
        self,
        codes: NDArray[np.int64],
        values: NDArray[np.float32],
        delta: float,
        clamp_min: float,
        clamp_max: float,
    ) -> None:
        codes = np.ascontiguousarray(codes, dtype=np.int64)
        clamps = (np.float32(delta), np.float32(clamp_min), np.float32(clamp_max))
        self._until_done(_update, (codes,), (values, *clamps))

    def _until_done(
        self, kernel: Callable[..., tuple[int, int, int]], items: tuple, rest: tuple
    ) -> None:
        """Run an update kernel (:func:`_update`, :func:`_update_tiles`) over its items from the
        first: ``kernel(table arrays, block count, *items, start, *rest)`` updates from item
        ``start`` on and returns (where it stopped, blocks in use, voxels added); when a block does
        not fit it stops there, and the table grows before it goes on."""
        n = items[0].shape[0]
        done = 0
        while True:
            done, self.nblocks, new = kernel(
                self.bkeys, self.bids, self._shift, self.vals, self.nblocks, *items, done, *rest
            )
            self.count += int(new)
            if done == n:
                return
            # out of room: grow as if each remaining item started a block, up to twice the size
            self.reserve_blocks(min(n - done, max(self.nblocks, 16)))

    def set(self, codes: NDArray[np.int64], values: NDArray[np.float32]) -> None:
        """Insert or overwrite; ``codes`` must be unique and ``values`` not NaN (NaN is how the
        table marks an unknown voxel)."""
        values = np.ascontiguousarray(values, dtype=np.float32)
        if values.shape != np.shape(codes):
            raise GeometryError(f"{np.shape(codes)} codes but {values.shape} values")
        if np.isnan(values).any():
            raise GeometryError("a voxel's value must not be NaN (NaN marks unknown voxels)")
        if values.size:
            self.reserve_blocks(np.unique(np.asarray(codes) >> BLOCK_BITS).size)
            self._apply(codes, values, 0.0, 0.0, 0.0)

    def add_logodds(
        self, codes: NDArray[np.int64], delta: float, clamp_min: float, clamp_max: float
    ) -> None:
        """Add ``delta`` to each (unique) code's log-odds, creating at 0, clamping (float32). The
        table grows only for the blocks actually added: most of a scan's voxels are known."""
        self._apply(codes, np.empty(0, np.float32), delta, clamp_min, clamp_max)

    def add_logodds_tiles(
        self,
        blocks: NDArray[np.int64],
        masks: NDArray[np.uint64],
        delta: float,
        clamp_min: float,
        clamp_max: float,
    ) -> None:
        """:meth:`add_logodds` of the voxels of tiles (unique block codes ``blocks`` (m,) and their
        ``masks`` (m,) uint64, :mod:`secure3d.mapping.morton`'s tile form): the same values, one
        hash probe per tile instead of a code per voxel."""
        blocks = np.ascontiguousarray(blocks, dtype=np.int64)
        if blocks.shape != np.shape(masks) or blocks.ndim != 1:
            raise GeometryError(f"tiles: {blocks.shape} block codes but {np.shape(masks)} masks")
        masks = _tile_masks(masks)  # non-negative integers, as morton's tile functions take them
        clamps = (np.float32(delta), np.float32(clamp_min), np.float32(clamp_max))
        self._until_done(_update_tiles, (blocks, masks), clamps)

    def _blocks(self) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        """Codes (n, BLOCK) and values (n, BLOCK) of the blocks in use, blocks sorted by code (so
        both read row by row are sorted)."""
        used = np.flatnonzero(self.bkeys != _EMPTY)
        used = used[np.argsort(self.bkeys[used], kind="stable")]
        codes = (self.bkeys[used][:, None] << BLOCK_BITS) | np.arange(BLOCK, dtype=np.int64)
        return codes, self.vals.reshape(-1, BLOCK)[self.bids[used]]

    def items(self) -> tuple[NDArray[np.int64], NDArray[np.float32]]:
        """All (codes, values), sorted by code (depth-first octree order)."""
        codes, vals = self._blocks()
        known = ~np.isnan(vals)
        return codes[known], vals[known]

    def codes_at_least(self, threshold: float) -> NDArray[np.int64]:
        """The codes whose value is >= ``threshold``, sorted."""
        codes, vals = self._blocks()
        return codes[vals >= threshold]

    def copy(self) -> VoxelTable:
        out = VoxelTable.__new__(VoxelTable)
        out.bkeys = self.bkeys.copy()
        out.bids = self.bids.copy()
        out.vals = self.vals.copy()
        out.nblocks = self.nblocks
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
        codes = self.table.codes_at_least(threshold)
        if self.c_start.size:
            sel = self.c_val >= threshold
            ccodes, _ = expand_ranges(self.c_start[sel], self.c_depth[sel], limit - codes.size)
            codes = np.sort(np.concatenate([codes, ccodes]))
        return codes

    # ------------------------------------------------------------------ updates

    def add_logodds(
        self, codes: NDArray[np.int64], delta: float, clamp_min: float, clamp_max: float
    ) -> None:
        """OctoMap's per-voxel log-odds update for unique finest ``codes``."""
        if codes.size == 0:
            return
        self._split_coarse(codes)
        self.table.add_logodds(codes, delta, clamp_min, clamp_max)

    def add_logodds_tiles(
        self,
        blocks: NDArray[np.int64],
        masks: NDArray[np.uint64],
        delta: float,
        clamp_min: float,
        clamp_max: float,
    ) -> None:
        """:meth:`add_logodds` of the voxels of tiles (see :meth:`VoxelTable.add_logodds_tiles`)."""
        if self.c_start.size:  # coarse leaves to split first: by codes
            self.add_logodds(tiles_to_codes(blocks, masks), delta, clamp_min, clamp_max)
        elif blocks.size:
            self.table.add_logodds_tiles(blocks, masks, delta, clamp_min, clamp_max)

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
