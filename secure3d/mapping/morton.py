"""OctoMap's voxel keys and their Morton codes: coordinates <-> keys <-> codes (key arithmetic).

A coordinate is first rounded to ``float32`` (OctoMap's ``point3d``), then
``key = floor(c * (1/res)) + 32768`` in double precision; keys live in ``[0, 65536)`` (16 levels).
Voxels are identified by a 48-bit *Morton code* (bits of x, y, z interleaved, x lowest), stored as
``int64``. In Morton order the 8 children of an octree node are consecutive and a node at depth
``d`` is the code shifted right by ``3 * (16 - d)``, so sorted codes are the octree's depth-first
order: this is what makes ``.bt`` reading, writing and pruning vectorisable. (Overview of the
OctoMap-exact mapping: :mod:`secure3d.mapping.keys`.)
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import GeometryError

__all__ = [
    "KEY_LIMIT",
    "TREE_DEPTH",
    "TILE_BITS",
    "TREE_MAX_VAL",
    "box_codes",
    "box_keys",
    "codes_to_coords",
    "codes_to_tiles",
    "coords_to_codes",
    "coords_to_keys",
    "keys_to_coords",
    "morton_decode",
    "morton_encode",
    "tile_voxel_count",
    "tiles_in_box",
    "tiles_to_codes",
    "unique_sorted",
]

#: OctoMap's tree depth and key offset (``tree_max_val``): keys are in ``[0, 2 * TREE_MAX_VAL)``.
TREE_DEPTH = 16
TREE_MAX_VAL = 32768
KEY_LIMIT = 2 * TREE_MAX_VAL

#: The code of no voxel (an invalid row of :func:`coords_to_codes`, an empty hash-table slot).
EMPTY = -1


# --------------------------------------------------------------------------- Morton codes


@numba.njit(cache=True, inline="always")
def _spread16(v: int) -> int:
    """Insert two zero bits between each of the low 16 bits of ``v`` (numba and numpy ints)."""
    v = v & 0xFFFF
    v = (v | (v << 16)) & 0x0000FF0000FF
    v = (v | (v << 8)) & 0x00F00F00F00F
    v = (v | (v << 4)) & 0x0C30C30C30C3
    v = (v | (v << 2)) & 0x249249249249
    return v


@numba.njit(cache=True, inline="always")
def _compact16(v: int) -> int:
    """Inverse of :func:`_spread16`: gather every third bit of ``v`` into 16 bits."""
    v = v & 0x249249249249
    v = (v | (v >> 2)) & 0x0C30C30C30C3
    v = (v | (v >> 4)) & 0x00F00F00F00F
    v = (v | (v >> 8)) & 0x0000FF0000FF
    v = (v | (v >> 16)) & 0xFFFF
    return v


_DEBRUIJN = np.uint64(0x03F79D71B4CB0A89)
_DEBRUIJN_SHIFT = np.uint64(58)


def _debruijn_table() -> NDArray[np.int64]:
    table = np.zeros(64, np.int64)
    for i in range(64):
        table[((1 << i) * 0x03F79D71B4CB0A89 % (1 << 64)) >> 58] = i
    return table


_CTZ = _debruijn_table()


@numba.njit(cache=True, inline="always")
def _ctz(w: np.uint64) -> int:
    """Index of the lowest set bit of ``w`` (nonzero): a de Bruijn multiply and a table lookup."""
    low = w & (~w + np.uint64(1))
    return _CTZ[(low * _DEBRUIJN) >> _DEBRUIJN_SHIFT]


@numba.njit(cache=True, inline="always")
def _morton3(kx: int, ky: int, kz: int) -> int:
    return _spread16(kx) | (_spread16(ky) << 1) | (_spread16(kz) << 2)


def morton_encode(keys: ArrayLike) -> NDArray[np.int64]:
    """Morton codes of OctoMap keys.

    Parameters
    ----------
    keys : (n, 3) int
        Keys in ``[0, 65536)``.

    Returns
    -------
    (n,) int64
        Codes with x in bit 0, y in bit 1, z in bit 2 of every 3-bit group, so the octree child
        index at tree level ``l`` (root = 0) is ``(code >> 3 * (15 - l)) & 7 = x + 2y + 4z``,
        OctoMap's ``computeChildIdx``.
    """
    k = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    return _spread16(k[:, 0]) | (_spread16(k[:, 1]) << 1) | (_spread16(k[:, 2]) << 2)


def morton_decode(codes: ArrayLike) -> NDArray[np.int64]:
    """Keys of Morton codes: the inverse of :func:`morton_encode`.

    Parameters
    ----------
    codes : (n,) int64

    Returns
    -------
    (n, 3) int64
    """
    c = np.asarray(codes, dtype=np.int64).ravel()
    return np.stack([_compact16(c), _compact16(c >> 1), _compact16(c >> 2)], axis=1)


# --------------------------------------------------------------------------- coordinates <-> keys


def coords_to_keys(
    points: ArrayLike, resolution: float
) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """OctoMap keys of points (``coordToKeyChecked`` on ``float32`` coordinates).

    Parameters
    ----------
    points : (n, 3) float
    resolution : float
        Voxel edge length (m).

    Returns
    -------
    keys : (n, 3) int64
        Keys; rows that are not valid hold 0.
    valid : (n,) bool
        False where a coordinate is not finite or falls outside the key range.
    """
    p32 = np.asarray(points, dtype=np.float64).reshape(-1, 3).astype(np.float32)
    with np.errstate(invalid="ignore", over="ignore"):
        scaled = np.floor(p32.astype(np.float64) * (1.0 / resolution))
        valid = np.all((scaled >= -TREE_MAX_VAL) & (scaled < TREE_MAX_VAL), axis=1)
    keys = np.zeros(scaled.shape, dtype=np.int64)
    keys[valid] = scaled[valid].astype(np.int64) + TREE_MAX_VAL
    return keys, valid


@numba.njit(cache=True)
def _box_codes_kernel(keys_lo: np.ndarray, keys_hi: np.ndarray, total: int) -> np.ndarray:
    out = np.empty(total, np.int64)
    n = 0
    for b in range(keys_lo.shape[0]):
        for kz in range(keys_lo[b, 2], keys_hi[b, 2] + 1):
            mz = _spread16(kz) << 2
            for ky in range(keys_lo[b, 1], keys_hi[b, 1] + 1):
                myz = mz | (_spread16(ky) << 1)
                for kx in range(keys_lo[b, 0], keys_hi[b, 0] + 1):
                    out[n] = myz | _spread16(kx)
                    n += 1
    return out


def box_codes(keys_lo: ArrayLike, keys_hi: ArrayLike) -> NDArray[np.int64]:
    """Morton codes of every cell of inclusive key boxes (x fastest within a box, boxes in order;
    a cell in two boxes appears twice, an empty box adds nothing): ``morton_encode`` of all their
    cells without listing the keys first.

    Parameters
    ----------
    keys_lo, keys_hi : (n, 3) int
        Inclusive key bounds, inside ``[0, KEY_LIMIT)`` (``hi < lo`` on an axis: empty box).
    """
    lo = np.ascontiguousarray(np.asarray(keys_lo, dtype=np.int64).reshape(-1, 3))
    hi = np.ascontiguousarray(np.asarray(keys_hi, dtype=np.int64).reshape(-1, 3))
    if lo.shape != hi.shape:
        raise GeometryError(f"box_codes: lo and hi shapes differ, {lo.shape} vs {hi.shape}")
    ext = np.maximum(hi - lo + 1, 0)
    nonempty = np.all(ext > 0, axis=1)
    if np.any(lo[nonempty] < 0) or np.any(hi[nonempty] >= KEY_LIMIT):
        raise GeometryError(f"box_codes: keys must lie in [0, {KEY_LIMIT})")
    total = int(np.prod(ext, axis=1).sum())
    return _box_codes_kernel(lo[nonempty], hi[nonempty], total)


def unique_sorted(values: ArrayLike) -> NDArray[np.int64]:
    """Sorted distinct values of a 1-D integer array, as ``np.unique`` but by sorting: numpy's
    hash-based ``unique`` takes ~15x as long on hundreds of thousands of Morton codes."""
    v = np.sort(np.asarray(values, dtype=np.int64).ravel())
    if v.size < 2:
        return v
    keep = np.empty(v.size, bool)
    keep[0] = True
    np.not_equal(v[1:], v[:-1], out=keep[1:])
    return v[keep]


def coords_to_codes(
    points: ArrayLike, resolution: float
) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Morton codes of points; see :func:`coords_to_keys`. Invalid rows hold ``-1``."""
    keys, valid = coords_to_keys(points, resolution)
    codes = morton_encode(keys)
    codes[~valid] = EMPTY
    return codes, valid


def keys_to_coords(keys: ArrayLike, resolution: float) -> NDArray[np.float64]:
    """Voxel centres of keys (OctoMap's ``keyToCoord`` at full depth).

    Parameters
    ----------
    keys : (n, 3) int
    resolution : float

    Returns
    -------
    (n, 3) float64
        ``(key - 32768 + 0.5) * resolution``.
    """
    k = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    return ((k - TREE_MAX_VAL).astype(np.float64) + 0.5) * resolution


def codes_to_coords(codes: ArrayLike, resolution: float) -> NDArray[np.float64]:
    """Voxel centres of Morton codes, ``(n, 3) float64``."""
    return keys_to_coords(morton_decode(codes), resolution)


# --------------------------------------------------------------------------- 4 x 4 x 4 tiles
#
# A *tile* is the 64 voxels whose Morton codes share all bits but the low six (a 4 x 4 x 4 cube,
# a block of :class:`~secure3d.mapping.store.VoxelTable`). A set of voxels as tiles is two arrays:
# the tiles' block codes (``code >> 6``) and one ``uint64`` mask per tile, bit ``i`` set when voxel
# ``block << 6 | i`` is in the set.

#: Bits of a Morton code inside its tile (4 x 4 x 4 = 2**6 voxels).
TILE_BITS = 6
_TILE_INNER = (1 << TILE_BITS) - 1


@numba.njit(cache=True)
def _popcount_sum(masks: np.ndarray) -> int:
    n = 0
    for i in range(masks.shape[0]):
        v = masks[i]
        v = v - ((v >> np.uint64(1)) & np.uint64(0x5555555555555555))
        v = (v & np.uint64(0x3333333333333333)) + (
            (v >> np.uint64(2)) & np.uint64(0x3333333333333333)
        )
        v = (v + (v >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
        n += np.int64((v * np.uint64(0x0101010101010101)) >> np.uint64(56))
    return n


def _tile_masks(masks: ArrayLike) -> NDArray[np.uint64]:
    """``masks`` as a flat uint64 array; anything but non-negative integers is refused."""
    m = np.asarray(masks)
    if m.size and (
        not np.issubdtype(m.dtype, np.integer)
        or (np.issubdtype(m.dtype, np.signedinteger) and m.min() < 0)
    ):
        raise GeometryError(
            f"tile masks: expected non-negative integers (uint64), got {m.dtype} {m.ravel()[:3]}"
        )
    return np.ascontiguousarray(m, dtype=np.uint64).reshape(-1)


def tile_voxel_count(masks: ArrayLike) -> int:
    """Number of voxels in tiles with these ``masks`` (uint64): their bits set."""
    return int(_popcount_sum(_tile_masks(masks)))


@numba.njit(cache=True)
def _tiles_to_codes_kernel(blocks: np.ndarray, masks: np.ndarray) -> np.ndarray:
    out = np.empty(_popcount_sum(masks), np.int64)
    j = 0
    for i in range(masks.shape[0]):
        m = masks[i]
        base = blocks[i] << TILE_BITS
        while m:
            out[j] = base | _ctz(m)
            j += 1
            m &= m - np.uint64(1)
    return out


def tiles_to_codes(blocks: ArrayLike, masks: ArrayLike) -> NDArray[np.int64]:
    """The voxels of tiles (``blocks`` (m,) int64, ``masks`` (m,) uint64) as Morton codes (n,),
    tile by tile, ascending within a tile."""
    blocks = np.ascontiguousarray(blocks, dtype=np.int64).reshape(-1)
    masks = _tile_masks(masks)
    if blocks.shape != masks.shape:
        raise GeometryError(f"tiles: {blocks.shape[0]} block codes but {masks.shape[0]} masks")
    return _tiles_to_codes_kernel(blocks, masks)


@numba.njit(cache=True)
def _sorted_codes_to_tiles(codes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    blocks = np.empty(codes.shape[0], np.int64)
    masks = np.zeros(codes.shape[0], np.uint64)
    m = -1
    for i in range(codes.shape[0]):
        b = codes[i] >> TILE_BITS
        if m < 0 or blocks[m] != b:
            m += 1
            blocks[m] = b
        masks[m] |= np.uint64(1) << np.uint64(codes[i] & _TILE_INNER)
    return blocks[: m + 1], masks[: m + 1]


def codes_to_tiles(codes: ArrayLike) -> tuple[NDArray[np.int64], NDArray[np.uint64]]:
    """Morton codes (n,) (non-negative; repeats allowed) as tiles: (block codes (m,) ascending,
    masks (m,))."""
    codes = np.asarray(codes, dtype=np.int64).reshape(-1)
    if codes.size and codes.min() < 0:
        raise GeometryError("codes_to_tiles: codes must be non-negative")
    return _sorted_codes_to_tiles(np.sort(codes))


def box_keys(box: ArrayLike, resolution: float) -> NDArray[np.int64]:
    """(2, 3) int64: the keys (rows lo, hi, inclusive) of the voxels that meet the box ``box``
    (rows lo, hi, m), within the key range. Raises :class:`GeometryError` for a box that is not
    two finite corners with lo <= hi."""
    try:
        b = np.asarray(box, dtype=np.float64)
    except (TypeError, ValueError):
        raise GeometryError(
            f"box: expected two corners (lo, hi) of 3 numbers, got {box!r}"
        ) from None
    if b.shape != (2, 3) or not np.all(np.isfinite(b)):
        raise GeometryError(f"box: expected two finite corners (lo, hi) of 3 numbers, got {box!r}")
    if np.any(b[0] > b[1]):
        raise GeometryError(f"box: lo {b[0].tolist()} must not exceed hi {b[1].tolist()}")
    keys = np.floor(b / float(resolution)) + TREE_MAX_VAL
    return np.clip(keys, 0, KEY_LIMIT - 1).astype(np.int64)


def tiles_in_box(
    blocks: NDArray[np.int64],
    masks: NDArray[np.uint64],
    codes: NDArray[np.int64],
    keep: NDArray[np.int64],
) -> tuple[NDArray[np.int64], NDArray[np.uint64], NDArray[np.int64]]:
    """Tiles (``blocks`` (m,), ``masks`` (m,)) and codes (k,) less their voxels outside the key box
    ``keep`` (2, 3) (rows lo, hi, inclusive): (blocks, masks, codes), the codes in their order.
    Raises :class:`GeometryError` for a ``keep`` that is not a (2, 3) integer key box."""
    keep = np.asarray(keep)
    if keep.shape != (2, 3) or not np.issubdtype(keep.dtype, np.integer):
        raise GeometryError(f"tiles_in_box: keep must be a (2, 3) integer key box, got {keep!r}")
    free = tiles_to_codes(blocks, masks)
    inside = [
        np.all((k >= keep[0]) & (k <= keep[1]), axis=1) for k in map(morton_decode, (free, codes))
    ]
    blocks, masks = codes_to_tiles(free[inside[0]])
    return blocks, masks, codes[inside[1]]
