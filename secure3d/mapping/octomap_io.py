"""OctoMap ``.bt`` (binary) and ``.ot`` (full) files: hardened readers, OctoMap-identical writers.

Both formats start with a text header (DESIGN.md section 5)::

    # Octomap OcTree binary file          (.ot: "# Octomap OcTree file")
    # (feel free to add / change comments, but leave the first line as it is!)
    #
    id OcTree
    size N                                 (number of nodes, inner and leaves)
    res 0.1
    data

followed by the nodes in depth-first pre-order, children in index order ``x + 2y + 4z``:

- ``.bt``: one 16-bit record per *inner* node, 2 bits per child (bits ``2i, 2i+1`` of the
  little-endian record): 0 absent, 1 free leaf, 2 occupied leaf, 3 inner node. Only the binary state
  survives: OctoMap sets read leaves to the clamping bounds (occupied = ``clamp_max``, free =
  ``clamp_min`` log-odds), so a ``.bt`` never round-trips log-odds.
- ``.ot``: per node its ``float32`` log-odds and a child-presence byte, so log-odds survive.

Leaves are exchanged with the rest of the package as Morton ranges: the first finest-level code of
the leaf (``prefix << 3 * (16 - depth)``) and its depth. Sorted by code this is the file order.

Readers never trust the file: the header is bounded, ``size`` is checked against what the body
can hold *before* allocating, recursion is an explicit stack bounded by the tree depth, and
truncation, trailing bytes, impossible depths and node-count mismatches all raise
:class:`MapFormatError` with the reason. Writers reproduce OctoMap's ``writeBinary``
(max-likelihood conversion, then ``prune()`` including its stop-at-the-first-level-without-pruning
rule) and ``write``.
"""

from __future__ import annotations

import bz2
import os
from pathlib import Path
from typing import NamedTuple

import numba
import numpy as np
from numpy.typing import NDArray

import secure3d._numba_cache  # noqa: F401  (kernels cached in the user's cache dir)
from secure3d.errors import MapFormatError
from secure3d.mapping.keys import TREE_DEPTH, unique_sorted
from secure3d.mapping.octomap_header import (
    BT_MAGIC,
    MAX_FILE_BYTES,
    MAX_HEADER_BYTES,
    OT_MAGIC,
    OT_NODE_BYTES,
    Header,
    parse_header,
    read_file_bounded,
)
from secure3d.mapping.octomap_header import (
    format_header as _header,
)

__all__ = [
    "BT_MAGIC",
    "MAX_HEADER_BYTES",
    "OT_MAGIC",
    "Leaves",
    "read_bt_bytes",
    "read_octomap_bytes",
    "read_octomap_file",
    "read_ot_bytes",
    "read_scan_dat",
    "write_bt_bytes",
    "write_ot_bytes",
]

#: Most leaves a file may hold (~1 GB of parsed arrays); geb079.bt, a whole building floor at
#: 0.08 m, has 428,144.
MAX_LEAVES = 100_000_000

# Error codes of the numba parsers.
_OK, _TRUNCATED, _TOO_DEEP, _TOO_MANY_NODES = 0, 1, 2, 3
_PARSE_ERRORS = {
    _TRUNCATED: "data ends in the middle of the tree (truncated file)",
    _TOO_DEEP: "an inner node sits at the maximum depth 16 (tree deeper than OctoMap's 16 levels)",
    _TOO_MANY_NODES: "the tree has more nodes than the header's size",
}


class Leaves(NamedTuple):
    """The leaves of an octree file.

    Attributes
    ----------
    resolution : float
        Voxel edge length (m).
    starts : (n,) int64
        First finest-level Morton code of each leaf, sorted.
    depths : (n,) int8
        Depth of each leaf (16 = one voxel, d covers ``8**(16-d)`` voxels).
    values : (n,) float32
        ``.ot``: the stored log-odds. ``.bt``: +1 for occupied, -1 for free (the reader of a map
        turns these into its clamping bounds, as OctoMap does).
    tree_id : str
        The header's ``id`` (the tree type that wrote the file).
    fmt : {"bt", "ot"}
        The file format (a ``.bt``'s values are only +-1).
    colors : (n, 3) uint8 or None
        Each leaf's r, g, b for a ``ColorOcTree`` ``.ot``; None otherwise (a ``.bt`` has none).
    """

    resolution: float
    starts: NDArray[np.int64]
    depths: NDArray[np.int8]
    values: NDArray[np.float32]
    tree_id: str = "OcTree"
    fmt: str = "bt"
    colors: NDArray[np.uint8] | None = None


# --------------------------------------------------------------------------- parsing kernels


@numba.njit(cache=True)
def _parse_bt_body(body: np.ndarray, max_nodes: int, n_out: int) -> tuple:
    """Walk ``.bt`` records; return (starts, depths, occupied, n_leaves, n_nodes, used, error).

    With ``n_out == 0`` nothing is stored (a validating count pass); otherwise ``n_out`` must be
    the leaf count of that pass.
    """
    n = body.shape[0]
    fill = n_out > 0
    starts = np.empty(n_out, np.int64)
    depths = np.empty(n_out, np.int8)
    occ = np.empty(n_out, np.bool_)
    stack_prefix = np.empty(TREE_DEPTH + 1, np.int64)
    stack_rec = np.empty(TREE_DEPTH + 1, np.int64)
    stack_next = np.empty(TREE_DEPTH + 1, np.int64)
    if max_nodes < 1:
        return starts, depths, occ, 0, 0, 0, _TOO_MANY_NODES
    if n < 2:
        return starts, depths, occ, 0, 0, 0, _TRUNCATED
    n_leaves = 0
    n_nodes = 1
    pos = 0
    sp = 0  # stack depth == tree depth of the node on top
    prefix = 0
    while True:
        # ---- read the record of the node (depth sp, prefix) at pos
        rec = np.int64(body[pos]) | (np.int64(body[pos + 1]) << 8)
        pos += 2
        if rec == 0:
            if sp > 0:
                # OctoMap reads an inner node without children as a leaf of value -FLT_MAX: free.
                if fill:
                    starts[n_leaves] = prefix << (3 * (TREE_DEPTH - sp))
                    depths[n_leaves] = sp
                    occ[n_leaves] = False
                n_leaves += 1
            else:
                # A childless root is itself a leaf; OctoMap leaves it at its default, occupied.
                if fill:
                    starts[0] = 0
                    depths[0] = 0
                    occ[0] = True
                n_leaves = 1
                return starts, depths, occ, n_leaves, n_nodes, pos, _OK
        else:
            for c in range(8):
                code = (rec >> (2 * c)) & 3
                if code == 0:
                    continue
                n_nodes += 1
                if n_nodes > max_nodes:
                    return starts, depths, occ, n_leaves, n_nodes, pos, _TOO_MANY_NODES
                if code == 3:
                    if sp + 1 >= TREE_DEPTH:
                        return starts, depths, occ, n_leaves, n_nodes, pos, _TOO_DEEP
                    continue
                if fill:
                    starts[n_leaves] = ((prefix << 3) | c) << (3 * (TREE_DEPTH - sp - 1))
                    depths[n_leaves] = sp + 1
                    occ[n_leaves] = code == 2
                n_leaves += 1
            stack_prefix[sp] = prefix
            stack_rec[sp] = rec
            stack_next[sp] = 0
            sp += 1
        # ---- find the next inner child to descend into, popping finished nodes
        while sp > 0:
            top = sp - 1
            r = stack_rec[top]
            c = stack_next[top]
            while c < 8 and ((r >> (2 * c)) & 3) != 3:
                c += 1
            if c < 8:
                stack_next[top] = c + 1
                prefix = (stack_prefix[top] << 3) | c
                break
            sp -= 1
        if sp == 0:
            return starts, depths, occ, n_leaves, n_nodes, pos, _OK
        if pos + 2 > n:
            return starts, depths, occ, n_leaves, n_nodes, pos, _TRUNCATED


@numba.njit(cache=True)
def _parse_ot_body(values: np.ndarray, masks: np.ndarray) -> tuple:
    """Walk ``.ot`` records; return (starts, depths, values, nodes, n_leaves, n_nodes, error).

    ``nodes`` is each leaf's record index (for per-node data such as colours).

    ``values``/``masks`` are the per-record log-odds and child masks, one per node in pre-order.
    """
    n = masks.shape[0]
    starts = np.empty(n, np.int64)
    depths = np.empty(n, np.int8)
    leaf_vals = np.empty(n, np.float32)
    leaf_node = np.empty(n, np.int64)
    stack_prefix = np.empty(TREE_DEPTH + 1, np.int64)
    stack_mask = np.empty(TREE_DEPTH + 1, np.int64)
    stack_next = np.empty(TREE_DEPTH + 1, np.int64)
    n_leaves = 0
    pos = 0
    sp = 0
    prefix = 0
    while True:
        if pos >= n:
            return starts, depths, leaf_vals, leaf_node, n_leaves, pos, _TRUNCATED
        m = np.int64(masks[pos])
        v = values[pos]
        pos += 1
        if m == 0:
            starts[n_leaves] = prefix << (3 * (TREE_DEPTH - sp))
            depths[n_leaves] = sp
            leaf_vals[n_leaves] = v
            leaf_node[n_leaves] = pos - 1
            n_leaves += 1
        else:
            if sp >= TREE_DEPTH:
                return starts, depths, leaf_vals, leaf_node, n_leaves, pos, _TOO_DEEP
            stack_prefix[sp] = prefix
            stack_mask[sp] = m
            stack_next[sp] = 0
            sp += 1
        while sp > 0:
            top = sp - 1
            c = stack_next[top]
            while c < 8 and ((stack_mask[top] >> c) & 1) == 0:
                c += 1
            if c < 8:
                stack_next[top] = c + 1
                prefix = (stack_prefix[top] << 3) | c
                break
            sp -= 1
        if sp == 0:
            return starts, depths, leaf_vals, leaf_node, n_leaves, pos, _OK


def _sorted(starts: np.ndarray, *per_leaf: np.ndarray) -> tuple:
    order = np.argsort(starts, kind="stable")
    return (starts[order], *(x[order] for x in per_leaf))


def _empty(header: Header) -> Leaves:
    empty = np.empty(0, np.int64)
    colored = header.fmt == "ot" and header.tree_id == "ColorOcTree"
    colors = np.empty((0, 3), np.uint8) if colored else None
    return Leaves(
        header.resolution,
        empty,
        np.empty(0, np.int8),
        np.empty(0, np.float32),
        header.tree_id,
        header.fmt,
        colors,
    )


def _expect(header: Header, fmt: str) -> None:
    if header.fmt != fmt:
        magic = BT_MAGIC if fmt == "bt" else OT_MAGIC
        raise MapFormatError(f"bad header: first line must start with {magic.decode()!r}")


def read_bt_bytes(data: bytes) -> Leaves:
    """Parse an OctoMap ``.bt`` buffer, whatever tree type wrote it (or a legacy binary header).

    Parameters
    ----------
    data : bytes
        The whole file.

    Returns
    -------
    Leaves
        ``values`` is +1 (occupied) / -1 (free); ``colors`` is None (a ``.bt`` keeps only
        occupancy bits).

    Raises
    ------
    MapFormatError
        Bad header (see :func:`~secure3d.mapping.octomap_header.parse_header`), ``size``
        impossible for the number of data bytes, truncated data, a tree deeper than 16 levels,
        node-count mismatch, or trailing bytes after the tree.
    """
    header = parse_header(data)
    _expect(header, "bt")
    size = header.size
    body = np.frombuffer(data, dtype=np.uint8, offset=header.offset)
    if size == 0:
        if body.size:
            raise MapFormatError(f"size 0 but {body.size} data bytes follow the header")
        return _empty(header)
    # Each 2-byte record declares at most 8 children: reject an impossible size outright.
    max_nodes = 1 + 8 * (body.size // 2)
    if size > max_nodes:
        raise MapFormatError(
            f"size {size} is impossible: {body.size} data bytes hold at most {max_nodes} nodes"
        )
    # First pass: validate and count without storing; allocate only for what the file holds.
    _, _, _, n_leaves, n_nodes, used, err = _parse_bt_body(body, size, 0)
    if err != _OK:
        raise MapFormatError(f"corrupt .bt data: {_PARSE_ERRORS[err]}")
    if used != body.size:
        raise MapFormatError(f"{body.size - used} trailing bytes after the tree")
    if n_nodes != size:
        raise MapFormatError(f"size mismatch: header says {size} nodes, data has {n_nodes}")
    if n_leaves > MAX_LEAVES:
        raise MapFormatError(f"{n_leaves} leaves exceed the limit of {MAX_LEAVES}")
    starts, depths, occ, _, _, _, _ = _parse_bt_body(body, size, n_leaves)
    values = np.where(occ, np.float32(1.0), np.float32(-1.0))
    return Leaves(header.resolution, *_sorted(starts, depths, values), header.tree_id, "bt")


def read_ot_bytes(data: bytes) -> Leaves:
    """Parse an OctoMap ``.ot`` buffer of an ``OcTree``, ``OcTreeStamped`` or ``ColorOcTree``.

    Returns
    -------
    Leaves
        ``values`` are the stored ``float32`` log-odds; ``colors`` the leaves' r, g, b for a
        ``ColorOcTree`` (else None; an ``OcTreeStamped`` file holds no timestamps).

    Raises
    ------
    MapFormatError
        As :func:`read_bt_bytes`, plus non-finite log-odds and tree types without a known layout.
    """
    header = parse_header(data)
    _expect(header, "ot")
    size = header.size
    width = OT_NODE_BYTES[header.tree_id]
    body = np.frombuffer(data, dtype=np.uint8, offset=header.offset)
    # Every node is exactly one record (its data, then the child mask).
    if body.size != width * size:
        if body.size < width * size:
            raise MapFormatError(
                f"size {size} needs {width * size} data bytes, file has {body.size} (truncated?)"
            )
        raise MapFormatError(f"{body.size - width * size} trailing bytes after {size} nodes")
    if size == 0:
        return _empty(header)
    if size > MAX_LEAVES:
        raise MapFormatError(f"{size} nodes exceed the limit of {MAX_LEAVES}")
    rec = body.reshape(size, width)
    values = np.ascontiguousarray(rec[:, :4]).view("<f4").ravel().astype(np.float32)
    masks = np.ascontiguousarray(rec[:, width - 1])
    starts, depths, leaf_vals, leaf_node, n_leaves, used, err = _parse_ot_body(values, masks)
    if err != _OK:
        raise MapFormatError(f"corrupt .ot data: {_PARSE_ERRORS[err]}")
    if used != size:
        raise MapFormatError(f"size mismatch: header says {size} nodes, tree has {used}")
    leaf_vals = leaf_vals[:n_leaves]
    if not np.all(np.isfinite(leaf_vals)):
        raise MapFormatError("non-finite log-odds in .ot leaves")
    per_leaf = [starts[:n_leaves], depths[:n_leaves], leaf_vals]
    colored = header.tree_id == "ColorOcTree"
    if colored:
        per_leaf.append(np.ascontiguousarray(rec[leaf_node[:n_leaves], 4:7]))
    out = _sorted(*per_leaf)
    return Leaves(header.resolution, *out[:3], header.tree_id, "ot", out[3] if colored else None)


def read_octomap_bytes(data: bytes) -> Leaves:
    """Parse any OctoMap occupancy file (``.bt``, legacy ``.bt`` or ``.ot``), by its header."""
    if parse_header(data).fmt == "bt":
        return read_bt_bytes(data)
    return read_ot_bytes(data)


def read_octomap_file(path: str | os.PathLike[str], limit: int = MAX_FILE_BYTES) -> Leaves:
    """Read an OctoMap file header first (see
    :func:`~secure3d.mapping.octomap_header.read_file_bounded`), then parse it.

    Raises
    ------
    MapFormatError
        Malformed, truncated, hostile or too large.
    OSError
        The file cannot be read.
    """
    return read_octomap_bytes(read_file_bounded(path, limit))


# --------------------------------------------------------------------------- tree structure


def prune(
    starts: NDArray[np.int64],
    depths: NDArray[np.int8],
    values: NDArray[np.float32],
    *,
    stop_at_first_unpruned_level: bool = False,
) -> tuple[NDArray[np.int64], NDArray[np.int8], NDArray[np.float32]]:
    """Collapse every node whose 8 children are leaves of identical value (OctoMap's pruning).

    Levels are processed bottom-up (nodes at depth 15 first), never the root. With
    ``stop_at_first_unpruned_level`` this is OctoMap's ``prune()``, which stops at the first level
    where nothing collapsed; without it, the fully pruned tree that OctoMap maintains while
    inserting (every update prunes its path).

    Parameters
    ----------
    starts : (n,) int64
        Leaf start codes, sorted.
    depths : (n,) int8
    values : (n,) float32

    Returns
    -------
    starts, depths, values
        The pruned leaves, sorted.
    """
    for k in range(TREE_DEPTH - 1, 0, -1):
        child = np.flatnonzero(depths == k + 1)
        collapsed = 0
        if child.size >= 8:
            parent = starts[child] >> (3 * (TREE_DEPTH - k))
            first = np.flatnonzero(np.r_[True, parent[1:] != parent[:-1]])
            count = np.diff(np.r_[first, child.size])
            vals = values[child]
            same = np.minimum.reduceat(vals, first) == np.maximum.reduceat(vals, first)
            group_ok = (count == 8) & same
            collapsed = int(group_ok.sum())
            if collapsed:
                # The 8 children are consecutive in code order and the parent starts where its
                # first child does: turn that child into the parent, drop the other 7.
                in_group = np.repeat(group_ok, count)
                is_first = np.zeros(child.size, bool)
                is_first[first] = True
                keep = np.ones(starts.size, bool)
                keep[child[in_group & ~is_first]] = False
                depths = depths.copy()
                depths[child[first[group_ok]]] = k
                starts, depths, values = starts[keep], depths[keep], values[keep]
        if stop_at_first_unpruned_level and collapsed == 0:
            break
    return starts, depths, values


def _inner_nodes(starts: NDArray[np.int64], depths: NDArray[np.int8]) -> list[NDArray[np.int64]]:
    """Prefixes of the inner nodes at each depth 0..15 (sorted): all proper ancestors of leaves."""
    return [unique_sorted(starts[depths > k] >> (3 * (TREE_DEPTH - k))) for k in range(TREE_DEPTH)]


def _preorder(prefix_by_depth: list[NDArray[np.int64]]) -> NDArray[np.int64]:
    """Depth-first order of nodes given per depth: by first finest code, ancestors first."""
    depth = np.concatenate([np.full(p.size, k, np.int64) for k, p in enumerate(prefix_by_depth)])
    first = np.concatenate([p << (3 * (TREE_DEPTH - k)) for k, p in enumerate(prefix_by_depth)])
    return np.lexsort((depth, first))


def write_bt_bytes(
    resolution: float, starts: NDArray[np.int64], depths: NDArray[np.int8], occupied: NDArray
) -> bytes:
    """Serialise leaves (already pruned as wanted) into a ``.bt`` buffer.

    Parameters
    ----------
    resolution : float
    starts : (n,) int64
        Sorted leaf start codes.
    depths : (n,) int8
    occupied : (n,) bool
    """
    if starts.size == 0:
        return _header(BT_MAGIC, 0, resolution)
    if starts.size == 1 and depths[0] == 0:
        return _header(BT_MAGIC, 1, resolution) + b"\x00\x00"
    inner = _inner_nodes(starts, depths)
    offsets = np.cumsum([0] + [p.size for p in inner])
    rec = np.zeros(int(offsets[-1]), np.int64)
    occupied = np.asarray(occupied, bool)
    for k in range(TREE_DEPTH):
        sel = depths == k + 1
        q = starts[sel] >> (3 * (TREE_DEPTH - k - 1))
        code = np.where(occupied[sel], 2, 1)
        if k + 1 < TREE_DEPTH:
            qi = inner[k + 1]
            q = np.concatenate([q, qi])
            code = np.concatenate([code, np.full(qi.size, 3)])
        idx = offsets[k] + np.searchsorted(inner[k], q >> 3)
        rec += np.bincount(idx, weights=code << (2 * (q & 7)), minlength=rec.size).astype(np.int64)
    order = _preorder(inner)
    body = rec[order].astype("<u2").tobytes()
    return _header(BT_MAGIC, rec.size + starts.size, resolution) + body


def write_ot_bytes(
    resolution: float,
    starts: NDArray[np.int64],
    depths: NDArray[np.int8],
    values: NDArray[np.float32],
) -> bytes:
    """Serialise leaves into a ``.ot`` buffer; inner nodes carry their children's maximum log-odds
    (OctoMap's ``updateOccupancyChildren``)."""
    if starts.size == 0:
        return _header(OT_MAGIC, 0, resolution)
    inner = _inner_nodes(starts, depths)
    leaf_prefix = [starts[depths == k] >> (3 * (TREE_DEPTH - k)) for k in range(TREE_DEPTH + 1)]
    leaf_value = [values[depths == k] for k in range(TREE_DEPTH + 1)]
    inner_value = [np.full(p.size, -np.inf, np.float32) for p in inner]
    inner_mask = [np.zeros(p.size, np.int64) for p in inner]
    for k in range(TREE_DEPTH - 1, -1, -1):
        q = leaf_prefix[k + 1]
        v = leaf_value[k + 1]
        if k + 1 < TREE_DEPTH:
            q = np.concatenate([q, inner[k + 1]])
            v = np.concatenate([v, inner_value[k + 1]])
        idx = np.searchsorted(inner[k], q >> 3)
        np.maximum.at(inner_value[k], idx, v)
        inner_mask[k] += np.bincount(idx, weights=1 << (q & 7), minlength=inner[k].size).astype(
            np.int64
        )
    nodes = [
        np.concatenate([inner[k] if k < TREE_DEPTH else np.empty(0, np.int64), leaf_prefix[k]])
        for k in range(TREE_DEPTH + 1)
    ]
    node_val = np.concatenate(
        [
            np.concatenate(
                [inner_value[k] if k < TREE_DEPTH else np.empty(0, np.float32), leaf_value[k]]
            )
            for k in range(TREE_DEPTH + 1)
        ]
    )
    node_mask = np.concatenate(
        [
            np.concatenate(
                [
                    inner_mask[k] if k < TREE_DEPTH else np.empty(0, np.int64),
                    np.zeros(leaf_prefix[k].size, np.int64),
                ]
            )
            for k in range(TREE_DEPTH + 1)
        ]
    )
    order = _preorder(nodes)
    rec = np.empty((order.size, 5), np.uint8)
    rec[:, :4] = node_val[order].astype("<f4").view(np.uint8).reshape(-1, 4)
    rec[:, 4] = node_mask[order]
    return _header(OT_MAGIC, order.size, resolution) + rec.tobytes()


def read_scan_dat(path: str | os.PathLike[str], max_bytes: int = 1 << 30) -> NDArray[np.float64]:
    """Read an OctoMap point file: whitespace-separated ``x y z`` per line (``.bz2`` accepted).

    Parameters
    ----------
    path : path
        ``scan.dat`` or ``scan.dat.bz2`` (decompressed by suffix).
    max_bytes : int
        Refuse more (decompressed) text than this.

    Returns
    -------
    (n, 3) float64

    Raises
    ------
    MapFormatError
        Non-numeric tokens, a token count not divisible by 3, or too much data.
    """
    p = Path(path)
    opener = bz2.open if p.suffix == ".bz2" else open
    with opener(p, "rb") as fh:
        raw = fh.read(max_bytes + 1)
    if len(raw) > max_bytes:
        raise MapFormatError(f"{p}: more than {max_bytes} bytes of text")
    try:
        values = np.array(raw.split(), dtype=np.float64)
    except ValueError:
        raise MapFormatError(f"{p}: non-numeric token in a point file") from None
    if values.size % 3:
        raise MapFormatError(f"{p}: {values.size} numbers is not a multiple of 3")
    return values.reshape(-1, 3)
