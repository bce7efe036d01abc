"""The voxel updates of a whole scan, OctoMap's ``computeUpdate``, batched over all rays.

A scan marks every ray voxel free and every endpoint occupied, each voxel once per scan, occupied
winning over free; ``clear_range`` may shorten how far a beam longer than ``max_range`` clears, for
sensors whose range limit is not a sphere. The kernel is a numba function over all rays at once
(each ray stepped as :mod:`secure3d.mapping.raycast` does). Per-scan de-duplication uses two dense
bitmaps (free, occupied) over the key box of the scan, a DDA step being one addition to a voxel's
index in it. Scans whose key box is too big for dense bitmaps use a chunked bitmap instead
(8x8x8-voxel chunks found through a small hash directory, :mod:`._scan_chunked`). The free voxels
come out as 4 x 4 x 4 tiles (:class:`ScanTiles`), the unit the voxel store updates in, or listed
as codes (:class:`ScanUpdate`). ``discretize`` reproduces OctoMap's
``computeDiscreteUpdate``: one ray per distinct end voxel.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import GeometryError
from secure3d.mapping._scan_chunked import _fib_slot, _scan_chunked_kernel
from secure3d.mapping.morton import (
    EMPTY,
    TILE_BITS,
    TREE_MAX_VAL,
    _morton3,
    _spread16,
    box_keys,
    codes_to_tiles,
    coords_to_keys,
    tiles_in_box,
    tiles_to_codes,
)
from secure3d.mapping.raycast import (
    _clipped_ends,
    _dda_setup,
    _dda_step,
    _key_of,
    check_origin,
    check_points,
)

__all__ = ["ScanTiles", "ScanUpdate", "scan_tiles", "scan_update"]

#: Largest key box (voxels) the dense kernel handles: two bitmaps of 2**27 bits = 32 MB of virtual
#: memory, of which only the touched pages are ever used. Bigger scans use the chunked kernel.
_DENSE_VOXEL_LIMIT = 1 << 27
#: Margin (voxels) around the box of a scan's end keys: DDA rounding may step one voxel beside the
#: segment's own box before it notices it has passed the end.
_BOX_PAD = 2


@numba.njit(cache=True)
def _idx_to_codes(idx: np.ndarray, lo: np.ndarray, dims: np.ndarray) -> np.ndarray:
    out = np.empty(idx.shape[0], np.int64)
    for j in range(idx.shape[0]):
        v = idx[j]
        kx = lo[0] + v % dims[0]
        v //= dims[0]
        out[j] = _morton3(kx, lo[1] + v % dims[1], lo[2] + v // dims[1])
    return out


@numba.njit(cache=True)
def _discretize_kernel(points: np.ndarray, resolution: float) -> tuple[np.ndarray, int, int]:
    """OctoMap's ``computeDiscreteUpdate`` front end: the centre of every distinct end voxel.

    Each point is rounded to float32 and keyed (``coordToKey``); the first point of each voxel adds
    the voxel's centre (``keyToCoord``, stored as float32, OctoMap's ``point3d``), in the order of
    first appearance. Returns (centres (m, 3) float64, non-finite points, points whose key is out of
    range). OctoMap does not check the key range here; such points are dropped instead.
    """
    n = points.shape[0]
    res_factor = 1.0 / resolution
    cap = 16
    while cap < 2 * n:
        cap *= 2
    shift = 64 - int(np.log2(cap))
    table = np.full(cap, EMPTY, np.int64)
    centres = np.empty((n, 3), np.float64)
    m = 0
    nonfinite = 0
    outside = 0
    for i in range(n):
        if not (
            np.isfinite(points[i, 0]) and np.isfinite(points[i, 1]) and np.isfinite(points[i, 2])
        ):
            nonfinite += 1
            continue
        kx = _key_of(np.float64(np.float32(points[i, 0])), res_factor)
        ky = _key_of(np.float64(np.float32(points[i, 1])), res_factor)
        kz = _key_of(np.float64(np.float32(points[i, 2])), res_factor)
        if kx < 0 or ky < 0 or kz < 0:
            outside += 1
            continue
        packed = kx | (ky << 16) | (kz << 32)
        h = _fib_slot(packed, shift)
        while table[h] != EMPTY and table[h] != packed:
            h = (h + 1) & (cap - 1)
        if table[h] == packed:
            continue
        table[h] = packed
        centres[m, 0] = np.float32((np.float64(kx - TREE_MAX_VAL) + 0.5) * resolution)
        centres[m, 1] = np.float32((np.float64(ky - TREE_MAX_VAL) + 0.5) * resolution)
        centres[m, 2] = np.float32((np.float64(kz - TREE_MAX_VAL) + 0.5) * resolution)
        m += 1
    return centres[:m], nonfinite, outside


@numba.njit(cache=True, inline="always")
def _in_keys(kx: int, ky: int, kz: int, keep: np.ndarray) -> bool:
    """Whether key (kx, ky, kz) lies in the key box ``keep`` (2, 3): rows lo, hi, inclusive."""
    return (
        keep[0, 0] <= kx <= keep[1, 0]
        and keep[0, 1] <= ky <= keep[1, 1]
        and keep[0, 2] <= kz <= keep[1, 2]
    )


@numba.njit(cache=True)
def _dense_occupied(
    end_keys: np.ndarray, status: np.ndarray, lo: np.ndarray, dims: np.ndarray, keep: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The hit rays' end voxels inside the key box ``keep`` (2, 3) of :func:`_dense_trace`: (their
    linear indices, each once in order of first appearance, the occupied bitmap)."""
    nxy = dims[0] * dims[1]
    total = nxy * dims[2]
    n = end_keys.shape[0]
    one = np.uint64(1)
    occ_bits = np.zeros((total + 63) >> 6, np.uint64)
    occ_idx = np.empty(min(total, n), np.int64)
    nocc = 0
    for i in range(n):
        if status[i] == 0 and _in_keys(end_keys[i, 0], end_keys[i, 1], end_keys[i, 2], keep):
            end_idx = (end_keys[i, 0] - lo[0]) + dims[0] * (end_keys[i, 1] - lo[1])
            end_idx += nxy * (end_keys[i, 2] - lo[2])
            w = end_idx >> 6
            m = one << np.uint64(end_idx & 63)
            if (occ_bits[w] & m) == 0:
                occ_bits[w] |= m
                occ_idx[nocc] = end_idx
                nocc += 1
    return occ_idx[:nocc], occ_bits


@numba.njit(cache=True, nogil=True)
def _dense_free(
    ends: np.ndarray,
    end_keys: np.ndarray,
    status: np.ndarray,
    origin: np.ndarray,
    resolution: float,
    lo: np.ndarray,
    dims: np.ndarray,
    start: int,
    stop: int,
    bits: np.ndarray,
    keep: np.ndarray,
) -> None:
    """The free voxels of rays ``start:stop`` (status 0 or 1) into ``bits``, the dense bitmap of
    :func:`_dense_trace`, each ray up to where it leaves the key box ``keep`` (2, 3) (inclusive;
    the origin's voxel lies in it). Runs without the GIL, so that parts of a scan trace in
    threads."""
    res_factor = 1.0 / resolution
    ox = origin[0]
    oy = origin[1]
    oz = origin[2]
    kox = _key_of(np.float64(ox), res_factor)
    koy = _key_of(np.float64(oy), res_factor)
    koz = _key_of(np.float64(oz), res_factor)
    nx = dims[0]
    nxy = dims[0] * dims[1]
    utotal = np.uint64(nxy * dims[2])
    origin_idx = (kox - lo[0]) + nx * (koy - lo[1]) + nxy * (koz - lo[2])
    one = np.uint64(1)
    for i in range(start, stop):
        if status[i] >= 2:
            continue
        ekx = end_keys[i, 0]
        eky = end_keys[i, 1]
        ekz = end_keys[i, 2]
        end_idx = (ekx - lo[0]) + nx * (eky - lo[1]) + nxy * (ekz - lo[2])
        if end_idx == origin_idx:
            continue
        if not _in_keys(ekx, eky, ekz, keep):
            end_idx = -1  # the ray leaves the box first: never stop at an index alias of its end
        # Every DDA step changes one key by one: a bound on this ray's steps.
        bound = abs(ekx - kox) + abs(eky - koy) + abs(ekz - koz) + 2
        length, sx, sy, sz, tmx, tmy, tmz, tdx, tdy, tdz = _dda_setup(
            ox, oy, oz, ends[i, 0], ends[i, 1], ends[i, 2], kox, koy, koz, resolution
        )
        stx = sx
        sty = sy * nx
        stz = sz * nxy
        idx = origin_idx
        kx, ky, kz = kox, koy, koz
        bits[idx >> 6] |= one << np.uint64(idx & 63)
        for _ in range(bound):
            axis, tmx, tmy, tmz = _dda_step(tmx, tmy, tmz, tdx, tdy, tdz)
            if axis == 0:
                idx += stx
                kx += sx
                if kx < keep[0, 0] or kx > keep[1, 0]:
                    break
            elif axis == 1:
                idx += sty
                ky += sy
                if ky < keep[0, 1] or ky > keep[1, 1]:
                    break
            else:
                idx += stz
                kz += sz
                if kz < keep[0, 2] or kz > keep[1, 2]:
                    break
            # Accumulated rounding can pass the end voxel without hitting it: stop there.
            if idx == end_idx or min(tmx, min(tmy, tmz)) > length:
                break
            if np.uint64(idx) >= utotal:
                break  # impossible inside the padded box; never write outside it
            bits[idx >> 6] |= one << np.uint64(idx & 63)


#: Rays a thread of :func:`_dense_trace` takes at least (fewer rays are traced by one thread).
_RAYS_PER_PART = 2048
#: Threads a scan's trace may use: ``$SECURE3D_SCAN_THREADS``, else the cores this process may run
#: on, at most this many.
_MAX_SCAN_THREADS = 4
_POOL: list = [None, 0, 0]  # [ThreadPoolExecutor, the pid that made it, its threads]


def scan_threads() -> int:
    """Threads a scan's trace may use (``$SECURE3D_SCAN_THREADS``, else the available cores, at most
    :data:`_MAX_SCAN_THREADS`)."""
    value = os.environ.get("SECURE3D_SCAN_THREADS", "").strip()
    if value:
        try:
            n = int(value)
        except ValueError:
            n = 0
        if n < 1:
            raise GeometryError(
                f"environment variable SECURE3D_SCAN_THREADS: must be a whole number >= 1, "
                f"got {value!r}"
            )
        return n
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(_MAX_SCAN_THREADS, cores))


def _trace_parts(rays: int) -> int:
    """How many threads :func:`_dense_trace` traces ``rays`` rays in."""
    return max(1, min(scan_threads(), rays // _RAYS_PER_PART))


def _pool(workers: int) -> ThreadPoolExecutor:
    """The threads the parts of a trace run in (made again in a forked child, and when more are
    needed)."""
    pool, pid, size = _POOL
    if pool is None or pid != os.getpid() or size < workers:
        pool = ThreadPoolExecutor(workers, thread_name_prefix="secure3d-scan")
        _POOL[:] = [pool, os.getpid(), workers]
    return pool


def _dense_trace(
    ends: np.ndarray,
    end_keys: np.ndarray,
    status: np.ndarray,
    origin: np.ndarray,
    resolution: float,
    lo: np.ndarray,
    dims: np.ndarray,
    parts: int = 1,
    keep: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OctoMap's ``computeUpdate`` over all rays into dense bitmaps of the key box, limited to the
    voxels of the key box ``keep`` (2, 3) int64 (inclusive, holding the origin's voxel; None: the
    whole box).

    Voxel ``k`` of the box ``lo``/``dims`` has linear index
    ``(kx - lo_x) + dims_x ((ky - lo_y) + dims_y (kz - lo_z))``; a DDA step is one addition to it.
    The rays are traced in ``parts`` contiguous parts, in threads, each into a bitmap of its own
    (the first into the result), the others then or-ed into it: the same bits for any ``parts``
    >= 1. Returns (linear indices of the occupied voxels, each once in order of
    first appearance, the free bitmap, the occupied bitmap).
    """
    if keep is None:
        keep = np.stack([lo, lo + dims - 1])
    occ_idx, occ_bits = _dense_occupied(end_keys, status, lo, dims, keep)
    n = ends.shape[0]
    parts = max(1, min(int(parts), n))
    free_bits = np.zeros(occ_bits.shape[0], np.uint64)  # calloc: pages zeroed when touched
    bounds = [c * n // parts for c in range(parts + 1)]
    args = (ends, end_keys, status, origin, resolution, lo, dims)
    others = []
    if parts > 1:
        pool = _pool(parts - 1)
        for c in range(1, parts):
            bits = np.zeros(occ_bits.shape[0], np.uint64)
            job = pool.submit(_dense_free, *args, bounds[c], bounds[c + 1], bits, keep)
            others.append((bits, job))
    _dense_free(*args, bounds[0], bounds[1], free_bits, keep)
    for bits, job in others:
        job.result()
        np.bitwise_or(free_bits, bits, out=free_bits)
    return occ_idx, free_bits, occ_bits


def _tile_inner() -> np.ndarray:
    """(4, 4, 4) [z, y, x]: the low six bits of a Morton code, voxel (x, y, z) of its 4 x 4 x 4
    tile (the blocks of :class:`~secure3d.mapping.store.VoxelTable`)."""
    out = np.zeros((4, 4, 4), np.int64)
    for z in range(4):
        for y in range(4):
            for x in range(4):
                for b in range(2):
                    out[z, y, x] |= ((x >> b) & 1) << (3 * b)
                    out[z, y, x] |= ((y >> b) & 1) << (3 * b + 1)
                    out[z, y, x] |= ((z >> b) & 1) << (3 * b + 2)
    return out


_TILE_INNER = _tile_inner()


def _row_masks() -> np.ndarray:
    """(16, 16) uint64: the tile-mask bits (bit ``i``: the voxel of Morton inner code ``i``) of the
    x bits ``b`` (a nibble) in row ``r = 4 z + y`` of a 4 x 4 x 4 tile."""
    inner = _TILE_INNER.reshape(16, 4)  # [r, x]
    out = np.zeros((16, 16), np.uint64)
    for r in range(16):
        for b in range(16):
            for x in range(4):
                if (b >> x) & 1:
                    out[r, b] |= np.uint64(1) << np.uint64(inner[r, x])
    return out


_ROW_MASKS = _row_masks()
#: Voxels along x in one bitmap word, and tiles (4 voxels wide) in it.
_WORD = 64
_TILES_PER_WORD = 16


@numba.njit(cache=True)
def _dense_tiles(
    free_bits: np.ndarray, occ_bits: np.ndarray, lo: np.ndarray, dims: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The free voxels of a dense scan (occupied wins over free within a scan) as 4 x 4 x 4 tiles:
    (block codes (m,) int64, masks (m,) uint64; :mod:`secure3d.mapping.morton`'s tile form).

    The box must be aligned to tiles (``lo`` multiples of 4, ``dims`` multiples of 4, x a multiple
    of 64 so that a row is whole words: :func:`_dense_box`). Tiles are read from 16 rows at a time
    (4 in y by 4 in z), one word (16 tiles) of each; a word column with no free bit in its 16 rows
    is skipped whole. A tile is a block of the voxel store: one hash probe and one stretch of
    memory update up to 64 voxels (:meth:`~secure3d.mapping.store.VoxelTable.add_logodds_tiles`).
    """
    nx, ny, nz = dims[0], dims[1], dims[2]
    wpr = nx // _WORD
    nib = np.uint64(15)
    # the box holds as many tiles as bitmap words (64 voxels each); untouched pages stay virtual
    blocks = np.empty(free_bits.shape[0], np.int64)
    masks = np.empty(free_bits.shape[0], np.uint64)
    rows = np.empty(16, np.int64)
    words = np.empty(16, np.uint64)  # free bits of one word column, row r = 4 z + y
    j = 0
    for tz in range(0, nz, 4):
        mz = _spread16(lo[2] + tz) << 2
        for ty in range(0, ny, 4):
            myz = mz | (_spread16(lo[1] + ty) << 1)
            for r in range(16):
                rows[r] = (ty + (r & 3) + ny * (tz + (r >> 2))) * wpr
            for wx in range(wpr):
                any_bits = np.uint64(0)
                for r in range(16):
                    w = rows[r] + wx
                    words[r] = free_bits[w] & ~occ_bits[w]
                    any_bits |= words[r]
                if any_bits == 0:
                    continue
                for t in range(_TILES_PER_WORD):
                    sh = np.uint64(4 * t)
                    if (any_bits >> sh) & nib == 0:
                        continue
                    m = np.uint64(0)
                    for r in range(16):
                        m |= _ROW_MASKS[r, (words[r] >> sh) & nib]
                    blocks[j] = (myz | _spread16(lo[0] + wx * _WORD + 4 * t)) >> TILE_BITS
                    masks[j] = m
                    j += 1
    return blocks[:j], masks[:j]


def _dense_box(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, dims) of the dense kernel's key box around keys ``lo..hi`` (3,): padded by
    :data:`_BOX_PAD`, aligned to 4 x 4 x 4 tiles, rows of whole 64-bit words (see
    :func:`_dense_tiles`)."""
    lo = (lo - _BOX_PAD) & ~np.int64(3)
    dims = hi + _BOX_PAD - lo + 1
    dims = (dims + 3) & ~np.int64(3)
    dims[0] = (dims[0] + _WORD - 1) // _WORD * _WORD
    return lo, dims


def _scan_dense(
    ends: np.ndarray,
    end_keys: np.ndarray,
    status: np.ndarray,
    origin: np.ndarray,
    resolution: float,
    lo: np.ndarray,
    dims: np.ndarray,
    keep: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(free tiles' block codes, their masks, occupied codes) of a scan whose key box fits dense
    bitmaps; only voxels of the key box ``keep`` (see :func:`_dense_trace`)."""
    parts = _trace_parts(len(ends))
    occ, free_bits, occ_bits = _dense_trace(
        ends, end_keys, status, origin, resolution, lo, dims, parts, keep
    )
    blocks, masks = _dense_tiles(free_bits, occ_bits, lo, dims)
    return blocks, masks, _idx_to_codes(occ, lo, dims)


class ScanUpdate(NamedTuple):
    """The voxel updates of one scan (OctoMap's ``computeUpdate``), each voxel listed once.

    Attributes
    ----------
    free : (m,) int64
        Morton codes of voxels to mark free (disjoint from ``occupied``).
    occupied : (k,) int64
        Morton codes of voxels to mark occupied.
    points_used : int
        Points whose ray was cast (including beams clipped at the maximum range).
    skipped_nonfinite : int
        Points with a NaN or infinite coordinate.
    skipped_out_of_range : int
        Points whose (clipped) end lies outside the key range; OctoMap drops these whole.
    clipped : int
        Beams longer than the maximum range (they only clear space).
    rays : int
        Rays cast: ``points_used``, or the distinct end voxels of a discretised scan.
    """

    free: NDArray[np.int64]
    occupied: NDArray[np.int64]
    points_used: int
    skipped_nonfinite: int
    skipped_out_of_range: int
    clipped: int
    rays: int


class ScanTiles(NamedTuple):
    """A scan's voxel updates (:class:`ScanUpdate`) with its free voxels as 4 x 4 x 4 tiles, the
    form the dense kernel builds and the voxel store updates block by block
    (:meth:`~secure3d.mapping.store.VoxelTable.add_logodds_tiles`); :meth:`free` lists them.

    Attributes
    ----------
    blocks, masks : (m,) int64, (m,) uint64
        The free voxels: tile ``i`` holds voxel ``blocks[i] << 6 | b`` for every set bit ``b`` of
        ``masks[i]`` (disjoint from ``occupied``; each tile once).
    occupied, points_used, skipped_nonfinite, skipped_out_of_range, clipped, rays
        As :class:`ScanUpdate`.
    """

    blocks: NDArray[np.int64]
    masks: NDArray[np.uint64]
    occupied: NDArray[np.int64]
    points_used: int
    skipped_nonfinite: int
    skipped_out_of_range: int
    clipped: int
    rays: int

    def free(self) -> NDArray[np.int64]:
        """Morton codes of the free voxels (tile by tile)."""
        return tiles_to_codes(self.blocks, self.masks)


def scan_update(
    points: ArrayLike,
    origin: ArrayLike,
    resolution: float,
    max_range: float | None = None,
    discretize: bool = False,
    clear_range: float | None = None,
    box: ArrayLike | None = None,
) -> ScanUpdate:
    """Voxel updates of one scan, exactly as OctoMap's ``insertPointCloud`` computes them.

    Parameters
    ----------
    points : (n, 3) float
        Measured end points in the world frame (m). Rows with NaN/inf are skipped and counted.
    origin : (3,) float
        Sensor position (m); must be finite and inside the key range.
    resolution : float
        Voxel edge length (m).
    max_range : float or None
        Beams longer than this (Euclidean, m) only clear space up to it; None or negative: no limit.
    discretize : bool
        OctoMap's ``insertPointCloud(..., discretize=true)`` (``computeDiscreteUpdate``): one ray
        per distinct end voxel, cast to the voxel's centre (see :func:`_discretize_kernel`). A depth
        camera puts several pixels in most voxels, so this casts several times fewer rays. The
        occupied voxels are those of the exact update except where a centre and its points fall on
        different sides of ``max_range``; free voxels differ where a ray to the centre crosses other
        voxels than the rays to the points. ``points_used`` then counts points in a cast voxel,
        ``clipped`` the clipped rays, ``rays`` the rays cast.
    clear_range : float or None
        How far a beam longer than ``max_range`` clears space (m); None: ``max_range``, as OctoMap.
        A sensor whose range limit is not a sphere (a z-depth limit) records every hit inside its
        limit with ``max_range`` beyond its farthest hit and clears no-return beams only as far as
        it surely saw, ``clear_range`` (see :meth:`OccupancyMap.insert_depth_image`).
    box : ((3,), (3,)) float or None
        Update only the voxels that meet this box (lo, hi corners, m): the same updates as without
        it, less those of voxels outside it (a scan's rays are traced as they are; a ray that
        leaves the box updates nothing beyond). The map's region of interest, such as a planning
        domain: the camera sees far beyond a room, and free space out there costs time and memory.

    Returns
    -------
    ScanUpdate
    """
    s = scan_tiles(points, origin, resolution, max_range, discretize, clear_range, box)
    return ScanUpdate(s.free(), *s[2:])


def scan_tiles(
    points: ArrayLike,
    origin: ArrayLike,
    resolution: float,
    max_range: float | None = None,
    discretize: bool = False,
    clear_range: float | None = None,
    box: ArrayLike | None = None,
) -> ScanTiles:
    """:func:`scan_update` with the free voxels as 4 x 4 x 4 tiles (:class:`ScanTiles`), as the
    dense kernel builds them: what :meth:`OccupancyMap.insert_point_cloud` feeds the voxel store,
    without listing every free voxel's code. Same parameters and errors as :func:`scan_update`."""
    keep = None if box is None else box_keys(box, resolution)
    p = np.ascontiguousarray(check_points(points))
    o = check_origin(origin, resolution)
    mr = -1.0 if max_range is None or not np.isfinite(max_range) else float(max_range)
    cr = mr if clear_range is None else float(clear_range)
    if mr >= 0.0 and not 0.0 <= cr <= mr:
        raise GeometryError(f"clear_range: must be in [0, max_range = {mr}], got {clear_range!r}")
    if discretize:
        centres, nonfinite, outside = _discretize_kernel(p, float(resolution))
        s = scan_tiles(
            centres, o.astype(np.float64), resolution, max_range, False, clear_range, box
        )
        used = p.shape[0] - nonfinite - outside
        return s._replace(
            points_used=used, skipped_nonfinite=nonfinite, skipped_out_of_range=outside
        )
    ends, keys, status, lo, hi = _clipped_ends(p, o, float(resolution), mr, cr)
    origin_key = coords_to_keys(o[None].astype(np.float64), resolution)[0][0]
    traced_in_box = keep is not None and bool(
        np.all((origin_key >= keep[0]) & (origin_key <= keep[1]))
    )
    if traced_in_box:  # each ray's voxels in the box are the ones before it first leaves it
        lo, hi = np.maximum(lo, keep[0]), np.minimum(hi, keep[1])
    lo, dims = _dense_box(lo, hi)
    dense = float(np.prod(dims.astype(np.float64))) <= _DENSE_VOXEL_LIMIT
    if dense:
        tiles = _scan_dense(
            ends, keys, status, o, float(resolution), lo, dims, keep if traced_in_box else None
        )
    else:
        free, occ = _scan_chunked_kernel(ends, keys, status, o, float(resolution))
        tiles = (*codes_to_tiles(free), occ)
    if keep is not None and not (dense and traced_in_box):
        tiles = tiles_in_box(*tiles, keep)
    blocks, masks, occ = tiles
    counts = np.bincount(status, minlength=4)
    used = int(counts[0] + counts[1])
    return ScanTiles(blocks, masks, occ, used, int(counts[2]), int(counts[3]), int(counts[1]), used)
