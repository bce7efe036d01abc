"""The chunked form of :mod:`secure3d.mapping.scan`'s whole-scan update, for scans whose key box is
too big for two dense bitmaps: the same voxels (OctoMap's ``computeUpdate``, each ray stepped as
:mod:`secure3d.mapping.raycast` does), de-duplicated in 8 x 8 x 8-voxel chunks found through a
small open-addressing directory (linear probing, Fibonacci hashing). A test compares it with the
dense kernel.
"""

from __future__ import annotations

import numba
import numpy as np

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.mapping.morton import EMPTY, KEY_LIMIT, _morton3
from secure3d.mapping.raycast import _dda_key_step, _dda_setup, _key_of

# Fibonacci hashing constant (2**64 / golden ratio): spreads clustered Morton codes over the table.
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


@numba.njit(cache=True, inline="always")
def _fib_slot(key: int, shift: int) -> int:
    return np.int64((np.uint64(key) * _GOLDEN) >> np.uint64(shift))


@numba.njit(cache=True)
def _dir_rehash(keys: np.ndarray, vals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Double an open-addressing table (linear probing, Fibonacci hashing), keeping its entries."""
    cap = keys.shape[0] * 2
    shift = 64 - int(np.log2(cap))
    nk = np.full(cap, EMPTY, np.int64)
    nv = np.empty(cap, np.int64)
    for i in range(keys.shape[0]):
        k = keys[i]
        if k != EMPTY:
            h = _fib_slot(k, shift)
            while nk[h] != EMPTY:
                h = (h + 1) & (cap - 1)
            nk[h] = k
            nv[h] = vals[i]
    return nk, nv


@numba.njit(cache=True)
def _grow_to(a: np.ndarray, need: int) -> np.ndarray:
    """A zero-padded copy of ``a`` with at least ``need`` rows (at least doubled)."""
    out = np.zeros((max(2 * a.shape[0], need),) + a.shape[1:], a.dtype)
    # element by element (both C-contiguous): an array slice assignment makes numba compile its
    # shape-mismatch message formatting (~3 s of first-run compilation)
    flat_out, flat_a = out.reshape(-1), a.reshape(-1)
    for i in range(flat_a.size):
        flat_out[i] = flat_a[i]
    return out


@numba.njit(cache=True)
def _chunked_batch(
    first: int,
    ends: np.ndarray,
    end_keys: np.ndarray,
    status: np.ndarray,
    origin_keys: np.ndarray,
    origin: np.ndarray,
    resolution: float,
    bits: np.ndarray,
    hkeys: np.ndarray,
    hvals: np.ndarray,
    free_keys: np.ndarray,
    free_chunk: np.ndarray,
    occ_keys: np.ndarray,
    state: np.ndarray,
) -> int:
    """Process rays from ``first`` while the arrays surely have room; return the next ray.

    ``state`` = [free count, occupied count, chunks, directory entries, log2 directory size]. No
    array is reallocated here (that would slow the loop down twofold); the caller grows them.
    """
    ox = origin[0]
    oy = origin[1]
    oz = origin[2]
    kox = origin_keys[0]
    koy = origin_keys[1]
    koz = origin_keys[2]
    nfree = state[0]
    nocc = state[1]
    nchunks = state[2]
    hcount = state[3]
    hshift = 64 - state[4]
    hmask = hkeys.shape[0] - 1
    last_cid = -1
    ci = 0
    i = first
    while i < ends.shape[0]:
        ray_status = status[i]
        if ray_status >= 2:
            i += 1
            continue
        ekx = end_keys[i, 0]
        eky = end_keys[i, 1]
        ekz = end_keys[i, 2]
        bound = abs(ekx - kox) + abs(eky - koy) + abs(ekz - koz) + 2
        if (
            nfree + bound > free_keys.shape[0]
            or nocc >= occ_keys.shape[0]
            or nchunks + bound + 1 > bits.shape[0]
            or 2 * (hcount + bound + 1) > hkeys.shape[0]
        ):
            break
        same_voxel = ekx == kox and eky == koy and ekz == koz
        if not same_voxel:
            length, sx, sy, sz, tmx, tmy, tmz, tdx, tdy, tdz = _dda_setup(
                ox, oy, oz, ends[i, 0], ends[i, 1], ends[i, 2], kox, koy, koz, resolution
            )
        kx = kox
        ky = koy
        kz = koz
        # One pass per voxel: the origin voxel, the DDA steps (free), then the end point
        # (occupied, only for a real hit). The end voxel itself is never marked free.
        for s in range(bound + 1):
            layer = 0
            if same_voxel or s == bound:
                layer = 1
            elif s > 0:
                kx, ky, kz, tmx, tmy, tmz = _dda_key_step(
                    kx, ky, kz, sx, sy, sz, tmx, tmy, tmz, tdx, tdy, tdz
                )
                if (kx == ekx and ky == eky and kz == ekz) or min(tmx, min(tmy, tmz)) > length:
                    layer = 1
            if layer == 1:
                if ray_status != 0:
                    break
                kx = ekx
                ky = eky
                kz = ekz
            if kx < 0 or ky < 0 or kz < 0 or kx >= KEY_LIMIT or ky >= KEY_LIMIT or kz >= KEY_LIMIT:
                break  # impossible (rays stay between valid keys); never pack a bad key
            cid = (kx >> 3) | ((ky >> 3) << 13) | ((kz >> 3) << 26)
            if cid != last_cid:
                last_cid = cid
                h = _fib_slot(cid, hshift)
                while True:
                    kk = hkeys[h]
                    if kk == cid:
                        ci = hvals[h]
                        break
                    if kk == EMPTY:
                        hkeys[h] = cid
                        hvals[h] = nchunks
                        ci = nchunks
                        nchunks += 1
                        hcount += 1
                        break
                    h = (h + 1) & hmask
            m = np.uint64(1) << np.uint64((kx & 7) | ((ky & 7) << 3))
            w = 8 * layer + (kz & 7)
            if (bits[ci, w] & m) == 0:
                bits[ci, w] |= m
                packed = kx | (ky << 16) | (kz << 32)
                if layer == 0:
                    free_keys[nfree] = packed
                    free_chunk[nfree] = ci
                    nfree += 1
                else:
                    occ_keys[nocc] = packed
                    nocc += 1
            if layer == 1:
                break
        i += 1
    state[0] = nfree
    state[1] = nocc
    state[2] = nchunks
    state[3] = hcount
    return i


@numba.njit(cache=True)
def _scan_chunked_kernel(
    ends: np.ndarray,
    end_keys: np.ndarray,
    status: np.ndarray,
    origin: np.ndarray,
    resolution: float,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_dense_trace` for scans of any extent, with sparse storage.

    Voxels are de-duplicated with bits in 8x8x8 chunks (8 words free, 8 words occupied), found
    through an open-addressing hash directory of chunk ids. Rays are processed in batches between
    which the arrays grow.
    """
    res_factor = 1.0 / resolution
    origin_keys = np.empty(3, np.int64)
    for a in range(3):
        origin_keys[a] = _key_of(np.float64(origin[a]), res_factor)
    bits = np.zeros((1 << 12, 16), np.uint64)
    hkeys = np.full(1 << 12, EMPTY, np.int64)
    hvals = np.empty(hkeys.shape[0], np.int64)
    free_keys = np.empty(1 << 16, np.int64)
    free_chunk = np.empty(1 << 16, np.int64)
    occ_keys = np.empty(1 << 14, np.int64)
    state = np.array([0, 0, 0, 0, 12], np.int64)
    i = 0
    while i < ends.shape[0]:
        i = _chunked_batch(
            i,
            ends,
            end_keys,
            status,
            origin_keys,
            origin,
            resolution,
            bits,
            hkeys,
            hvals,
            free_keys,
            free_chunk,
            occ_keys,
            state,
        )
        if i < ends.shape[0]:
            # Room for at least the ray that did not fit (arrays at least double).
            need = 3
            for a in range(3):
                need += abs(end_keys[i, a] - origin_keys[a])
            if state[0] + need > free_keys.shape[0]:
                free_keys = _grow_to(free_keys, state[0] + need)
                free_chunk = _grow_to(free_chunk, state[0] + need)
            if state[1] + 1 > occ_keys.shape[0]:
                occ_keys = _grow_to(occ_keys, state[1] + 1)
            if state[2] + need + 1 > bits.shape[0]:
                bits = _grow_to(bits, state[2] + need + 1)
            while 2 * (state[3] + need + 1) > hkeys.shape[0]:
                hkeys, hvals = _dir_rehash(hkeys, hvals)
                state[4] += 1

    # Occupied wins: drop free keys whose occupied bit is set; convert to Morton codes.
    nfree = state[0]
    free_out = np.empty(nfree, np.int64)
    nf = 0
    for j in range(nfree):
        key = free_keys[j]
        kx = key & 0xFFFF
        ky = (key >> 16) & 0xFFFF
        kz = key >> 32
        m = np.uint64(1) << np.uint64((kx & 7) | ((ky & 7) << 3))
        if (bits[free_chunk[j], 8 + (kz & 7)] & m) == 0:
            free_out[nf] = _morton3(kx, ky, kz)
            nf += 1
    occ_out = np.empty(state[1], np.int64)
    for j in range(state[1]):
        key = occ_keys[j]
        occ_out[j] = _morton3(key & 0xFFFF, (key >> 16) & 0xFFFF, key >> 32)
    return free_out[:nf], occ_out
