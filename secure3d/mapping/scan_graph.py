"""OctoMap scan graphs: the ``.graph`` files of OctoMap's tools and their ``.log`` text form.

A scan graph is a sequence of scans, each a point cloud in its sensor's frame with the sensor's
pose; OctoMap's datasets (the Freiburg building and campus scans, from which ``geb079.bt`` was
built) are distributed this way, and ``graph2tree`` turns one into an OcTree by inserting every
scan from its pose's position.

``.graph`` (``ScanGraph::writeBinary``, little-endian)::

    uint32 n_nodes
    n_nodes x  { uint32 n_points, n_points x Vector3, Pose6D, uint32 id }
    uint32 n_edges
    n_edges x  { uint32 first_id, uint32 second_id, Pose6D constraint, float64 weight }

    Vector3    = int32 3, float64 x, y, z
    Quaternion = int32 4, float64 w, x, y, z
    Pose6D     = Vector3 translation, Quaternion rotation

``.log`` (``ScanGraph::readPlainASCII``, the input of ``log2graph``): a line
``NODE x y z roll pitch yaw`` starts a scan at that pose (radians, ``R = Rz(yaw) Ry(pitch)
Rx(roll)``), each further line ``x y z`` is one of its points; empty lines and lines starting with
``#`` or a space are skipped.

OctoMap keeps coordinates in ``float``; the readers round every value to float32 as it does and
return the points already transformed into the world frame (``R p + t``, rounded to float32 again:
bit for bit OctoMap's for an identity rotation, to float rounding otherwise).

The readers never trust the file: every count is checked against the bytes left before anything
is allocated, the ``3``/``4`` tags of vectors and quaternions must be present, poses must be
finite with unit quaternions, edges must name nodes of the graph, and truncation or trailing bytes
raise :class:`~secure3d.errors.MapFormatError` with the reason. Non-finite points are dropped (as
OctoMap's ray insertion skips them).
"""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from secure3d.errors import GeometryError, MapFormatError

__all__ = [
    "MAX_GRAPH_BYTES",
    "ScanGraph",
    "euler_quaternion",
    "read_scan_graph",
    "read_scan_graph_bytes",
    "read_scan_log_bytes",
    "rotation_matrix",
    "write_scan_graph_bytes",
]

#: Largest scan-graph file read (bytes); OctoMap's FR-079 corridor graph is about 165 MB.
MAX_GRAPH_BYTES = 400_000_000

_POINT = np.dtype([("tag", "<i4"), ("xyz", "<f8", (3,))])
_NODE_MIN_BYTES = 4 + 64 + 4  # point count (0 points), pose, id
_POSE = struct.Struct("<i3di4d")
_EDGE = struct.Struct("<II")
_EDGE_BYTES = 8 + _POSE.size + 8
#: A quaternion whose norm differs from 1 by more than this is refused (OctoMap would scale the
#: scan by its squared norm).
_UNIT_TOL = 1e-3


class ScanGraph(NamedTuple):
    """The scans of a scan graph, in file order, in the world frame.

    Attributes
    ----------
    points : (n, 3) float64
        Every scan's finite points, transformed by its node's pose, scan after scan.
    offsets : (m + 1,) int64
        Scan ``i``'s points are ``points[offsets[i]:offsets[i + 1]]``.
    origins : (m, 3) float64
        Each scan's sensor position (its pose's translation).
    rotations : (m, 4) float64
        Each scan's pose rotation as a unit quaternion ``(w, x, y, z)``.
    ids : (m,) int64
        Each node's id.
    n_edges : int
        Number of edges (the readers validate them; planning does not use them).
    """

    points: NDArray[np.float64]
    offsets: NDArray[np.int64]
    origins: NDArray[np.float64]
    rotations: NDArray[np.float64]
    ids: NDArray[np.int64]
    n_edges: int = 0

    def point_origins(self) -> NDArray[np.float64]:
        """(n, 3) float64: each point's sensor position."""
        return np.repeat(self.origins, np.diff(self.offsets), axis=0)


def _unit_quaternion(q: object, what: str) -> NDArray[np.float64]:
    q = np.asarray(q, dtype=float)
    if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1) > _UNIT_TOL:
        raise GeometryError(f"{what}: a unit quaternion (w, x, y, z) is needed, got {q!r}")
    return q


def rotation_matrix(q: NDArray[np.float64]) -> NDArray[np.float64]:
    """(3, 3) rotation of the unit quaternion ``q = (w, x, y, z)`` (GeometryError otherwise)."""
    w, x, y, z = _unit_quaternion(q, "rotation_matrix")
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _quaternion_product(a: NDArray, b: NDArray) -> NDArray[np.float64]:
    """Hamilton product ``a b`` of quaternions ``(w, x, y, z)``."""
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def euler_quaternion(roll: float, pitch: float, yaw: float) -> NDArray[np.float64]:
    """Unit quaternion ``(w, x, y, z)`` of ``Rz(yaw) Ry(pitch) Rx(roll)`` (octomath's order)."""
    cr, sr = np.cos(roll / 2), np.sin(roll / 2)
    cp, sp = np.cos(pitch / 2), np.sin(pitch / 2)
    cy, sy = np.cos(yaw / 2), np.sin(yaw / 2)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def _checked_pose(t: NDArray, q: NDArray, where: str) -> tuple[NDArray, NDArray]:
    t = t.astype(np.float32).astype(np.float64)
    q = q.astype(np.float32).astype(np.float64)
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
        raise MapFormatError(f"{where}: the pose is not finite")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > _UNIT_TOL:
        raise MapFormatError(f"{where}: the pose's quaternion has norm {norm:.6g}, not 1")
    return t, q / norm


def _to_world(local: NDArray, t: NDArray, q: NDArray) -> NDArray[np.float64]:
    """(n, 3) float32-rounded local points -> world points, rounded to float32 like OctoMap."""
    local = local[np.all(np.isfinite(local), axis=1)].astype(np.float32).astype(np.float64)
    if np.array_equal(q, [1.0, 0.0, 0.0, 0.0]):
        world = local + t
    else:
        world = local @ rotation_matrix(q).T + t
    return world.astype(np.float32).astype(np.float64)


def _assemble(scans: list[tuple[NDArray, NDArray, NDArray, int]], n_edges: int) -> ScanGraph:
    sizes = [len(s[0]) for s in scans]
    return ScanGraph(
        points=np.concatenate([s[0] for s in scans]) if scans else np.empty((0, 3)),
        offsets=np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64),
        origins=np.array([s[1] for s in scans], float).reshape(-1, 3),
        rotations=np.array([s[2] for s in scans], float).reshape(-1, 4),
        ids=np.array([s[3] for s in scans], np.int64),
        n_edges=n_edges,
    )


def _read_pose(data: bytes, off: int, where: str) -> tuple[NDArray, NDArray]:
    if len(data) - off < _POSE.size:
        raise MapFormatError(f"{where}: the file ends inside a pose (truncated file)")
    tag3, *rest = _POSE.unpack_from(data, off)
    tag4 = rest[3]
    if tag3 != 3 or tag4 != 4:
        raise MapFormatError(
            f"{where}: a pose must be tagged 3 and 4 (got {tag3} and {tag4}); not a scan graph"
        )
    return _checked_pose(np.array(rest[:3]), np.array(rest[4:]), where)


def _read_node(data: bytes, off: int, i: int) -> tuple[tuple, int]:
    where = f"node {i} at byte {off}"
    if len(data) - off < _NODE_MIN_BYTES:
        raise MapFormatError(f"{where}: the file ends inside a node (truncated file)")
    (n,) = struct.unpack_from("<I", data, off)
    off += 4
    if n * _POINT.itemsize > len(data) - off - (_NODE_MIN_BYTES - 4):
        raise MapFormatError(f"{where}: {n} points do not fit in the rest of the file")
    rec = np.frombuffer(data, dtype=_POINT, count=n, offset=off)
    if n and np.any(rec["tag"] != 3):
        raise MapFormatError(f"{where}: a point is not tagged 3; not a scan graph")
    off += n * _POINT.itemsize
    t, q = _read_pose(data, off, where)
    off += _POSE.size
    (node_id,) = struct.unpack_from("<I", data, off)
    return (_to_world(rec["xyz"], t, q), t, q, node_id), off + 4


def _read_edges(data: bytes, off: int, ids: set[int]) -> int:
    if off == len(data):  # no edge count: OctoMap reads 0 edges
        return 0
    if len(data) - off < 4:
        raise MapFormatError(f"byte {off}: the file ends inside the edge count (truncated file)")
    (m,) = struct.unpack_from("<I", data, off)
    off += 4
    if m * _EDGE_BYTES != len(data) - off:
        raise MapFormatError(
            f"byte {off}: {m} edges need {m * _EDGE_BYTES} bytes, {len(data) - off} are left"
            " (truncated file or trailing bytes)"
        )
    for k in range(m):
        first, second = _EDGE.unpack_from(data, off)
        if first not in ids or second not in ids:
            raise MapFormatError(f"edge {k}: it joins nodes {first} and {second}, not in the graph")
        _read_pose(data, off + _EDGE.size, f"edge {k}")
        off += _EDGE_BYTES
    return m


def read_scan_graph_bytes(data: bytes) -> ScanGraph:
    """Parse a binary ``.graph`` (see the module docstring).

    Raises
    ------
    MapFormatError
        Truncated, trailing bytes, missing tags, counts larger than the file, non-finite poses,
        non-unit quaternions, edges to unknown nodes, or no points at all.
    """
    if len(data) < 4:
        raise MapFormatError("the file is shorter than a node count (empty or truncated)")
    (n_nodes,) = struct.unpack_from("<I", data, 0)
    if n_nodes * _NODE_MIN_BYTES > len(data) - 4:
        raise MapFormatError(f"{n_nodes} nodes do not fit in {len(data)} bytes; not a scan graph")
    off, scans = 4, []
    for i in range(n_nodes):
        scan, off = _read_node(data, off, i)
        scans.append(scan)
    n_edges = _read_edges(data, off, {s[3] for s in scans})
    graph = _assemble(scans, n_edges)
    if len(graph.points) == 0:
        raise MapFormatError("the scan graph holds no finite points")
    return graph


def _log_blocks(lines: list[str]) -> list[tuple[int, str, list[str], list[int]]]:
    """The scans of a scan log's lines: (line number, NODE line, its point lines, their numbers)."""
    blocks: list[tuple[int, str, list[str], list[int]]] = []
    for no, line in enumerate(lines, 1):
        if not line or line[0] in "# \t\r":
            continue
        if line.startswith("NODE"):
            blocks.append((no, line, [], []))
        elif not blocks:
            raise MapFormatError(f"line {no}: a point before the first NODE line")
        else:
            blocks[-1][2].append(line)
            blocks[-1][3].append(no)
    return blocks


def _log_points(block: list[str], numbers: list[int]) -> NDArray[np.float64]:
    """(n, 3) points of one scan's lines; a bad line is named by its number."""
    try:  # every line x y z: one parse of the whole block
        values = np.array(" ".join(block).split(), dtype=np.float64)
        if values.size == 3 * len(block):
            return values.reshape(-1, 3)
    except ValueError:
        pass
    for k, line in zip(numbers, block, strict=True):  # find the bad line
        words = line.split()
        try:
            np.array(words[:3], dtype=np.float64)
        except ValueError:
            raise MapFormatError(f"line {k}: not numbers: {line[:60]!r}") from None
        if len(words) < 3:
            raise MapFormatError(f"line {k}: a point needs x y z")
    # extra words after x y z, as OctoMap reads them: keep the first three of each line
    return np.array([line.split()[:3] for line in block], dtype=np.float64).reshape(-1, 3)


def read_scan_log_bytes(data: bytes) -> ScanGraph:
    """Parse OctoMap's text scan log (``.log``, the input of ``log2graph``).

    Raises
    ------
    MapFormatError
        A point before the first ``NODE`` line, a line that is not numbers, a ``NODE`` line
        without six numbers, non-finite poses, or no points at all.
    """
    done = []
    lines = data.decode("utf-8", "replace").splitlines()
    for i, (no, node, block, numbers) in enumerate(_log_blocks(lines)):
        try:
            values = np.array(node.split()[1:], dtype=np.float64)
        except ValueError:
            raise MapFormatError(f"line {no}: not numbers: {node[:60]!r}") from None
        if values.size != 6:
            raise MapFormatError(f"line {no}: NODE needs x y z roll pitch yaw")
        rpy = values[3:].astype(np.float32).astype(np.float64)
        t, q = _checked_pose(values[:3], euler_quaternion(*rpy), f"line {no}")
        done.append((_to_world(_log_points(block, numbers), t, q), t, q, i))
    graph = _assemble(done, max(len(done) - 1, 0))  # log2graph joins consecutive nodes
    if len(graph.points) == 0:
        raise MapFormatError("the scan log holds no points")
    return graph


def read_scan_graph(path: str | os.PathLike[str], max_bytes: int = MAX_GRAPH_BYTES) -> ScanGraph:
    """Read a ``.graph`` (binary) or ``.log`` (text) scan graph file.

    Raises
    ------
    MapFormatError
        The file is larger than ``max_bytes`` or malformed; the message names the file.
    OSError
        It cannot be opened.
    """
    p = Path(path)
    with p.open("rb") as fh:
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise MapFormatError(f"{p}: larger than {max_bytes} bytes")
    try:
        if p.suffix.lower() == ".log":
            return read_scan_log_bytes(data)
        return read_scan_graph_bytes(data)
    except MapFormatError as exc:
        raise MapFormatError(f"{p}: {exc}") from None


def write_scan_graph_bytes(
    scans: list[tuple[NDArray, NDArray, NDArray]], edges: bool = True
) -> bytes:
    """A binary ``.graph`` as ``ScanGraph::writeBinary`` writes it.

    Parameters
    ----------
    scans : list of (points (n, 3), translation (3,), quaternion (4,) as w, x, y, z)
        Points in the sensor frame; node ids are 0, 1, ...
    edges : bool
        Join consecutive nodes by edges (``connectPrevious``), weight 1.
    """
    out = [struct.pack("<I", len(scans))]
    poses = []
    for i, (pts, t, q) in enumerate(scans):
        pts, t = np.asarray(pts, np.float64), np.asarray(t, np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or t.shape != (3,):
            raise GeometryError(
                f"scan {i}: points must be (n, 3) and the translation (3,), got {pts.shape}, {t.shape}"
            )
        if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(t))):
            raise GeometryError(f"scan {i}: points and translation must be finite")
        q = _unit_quaternion(q, f"scan {i}")
        rec = np.empty(len(pts), _POINT)
        rec["tag"], rec["xyz"] = 3, pts.astype(np.float32)
        pose = _POSE.pack(3, *np.asarray(t, float), 4, *np.asarray(q, float))
        out += [struct.pack("<I", len(pts)), rec.tobytes(), pose, struct.pack("<I", i)]
        poses.append((np.asarray(t, float), np.asarray(q, float)))
    links = range(1, len(scans)) if edges else range(0)
    out.append(struct.pack("<I", len(links)))
    for i in links:
        (t1, q1), (t2, q2) = poses[i - 1], poses[i]
        inv1 = q1 * np.array([1.0, -1.0, -1.0, -1.0])  # first.pose.inv() * second.pose
        rel = _POSE.pack(3, *(rotation_matrix(q1).T @ (t2 - t1)), 4, *_quaternion_product(inv1, q2))
        out += [_EDGE.pack(i - 1, i), rel, struct.pack("<d", 1.0)]
    return b"".join(out)
