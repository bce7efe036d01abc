"""OctoMap scan graphs (``.graph``, ``.log``): OctoMap's own sample graph against octomap-python,
poses against scipy's rotations, and hostile files."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import octomap
import pytest
from scipy.spatial.transform import Rotation

from secure3d.errors import MapFormatError
from secure3d.mapping import OccupancyMap
from secure3d.mapping.scan_graph import (
    read_scan_graph,
    read_scan_graph_bytes,
    read_scan_log_bytes,
    write_scan_graph_bytes,
)


def test_octomaps_spherical_scan_graph_reads_and_inserts_as_octomap_does(
    octomap_dir, octomap_voxels
) -> None:
    path = octomap_dir / "spherical_scan.graph"
    raw = path.read_bytes()
    graph = read_scan_graph(path)
    # Independent byte reading of the one node: count, points, pose.
    (nodes, n) = struct.unpack_from("<II", raw, 0)
    assert (nodes, n) == (1, 10201) and graph.offsets.tolist() == [0, n]
    local = np.array([struct.unpack_from("<3d", raw, 8 + 28 * i + 4) for i in range(n)])
    tx, ty, tz = struct.unpack_from("<3d", raw, 8 + 28 * n + 4)
    np.testing.assert_array_equal(graph.origins, [[tx, ty, tz]])
    np.testing.assert_array_equal(graph.rotations, [[1.0, 0.0, 0.0, 0.0]])
    want = (local.astype(np.float32) + np.float32([tx, ty, tz])).astype(np.float64)
    np.testing.assert_array_equal(graph.points, want)
    assert graph.n_edges == 0 and graph.ids.tolist() == [0]
    # A spherical cap 4.01 m from the sensor.
    r = np.linalg.norm(graph.points - graph.origins[0], axis=1)
    assert np.allclose(r, 4.01, atol=1e-3)
    # graph2tree: the scan inserted from its pose; every voxel the same as octomap-python's.
    ours = OccupancyMap(0.1)
    ours.insert_point_cloud(graph.points, graph.origins[0], None)
    tree = octomap.OcTree(0.1)
    tree.insertPointCloud(graph.points, graph.origins[0])
    occ, free = ours.occupied_voxels(), ours.free_voxels()
    assert (len(occ), len(free)) == octomap_voxels(tree) and len(free) > 10_000
    np.testing.assert_array_equal(tree.getLabels(occ), 1)
    np.testing.assert_array_equal(tree.getLabels(free), 0)


def _three_scans(rng: np.random.Generator) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    rots = Rotation.from_euler("ZYX", [[0.0, 0.0, 0.0], [1.2, 0.3, -0.2], [-2.5, -0.1, 0.4]])
    return [
        (rng.uniform(-3, 3, (50 + 10 * i, 3)), rng.uniform(-5, 5, 3), np.roll(q, 1))
        for i, q in enumerate(rots.as_quat())  # scipy's (x, y, z, w) -> (w, x, y, z)
    ]


def test_rotated_poses_transform_points_as_scipy_does() -> None:
    scans = _three_scans(np.random.default_rng(1))
    graph = read_scan_graph_bytes(write_scan_graph_bytes(scans))
    assert graph.n_edges == 2 and graph.ids.tolist() == [0, 1, 2]
    for i, (pts, t, q) in enumerate(scans):
        got = graph.points[graph.offsets[i] : graph.offsets[i + 1]]
        want = Rotation.from_quat(np.roll(q, -1)).apply(pts) + t
        np.testing.assert_allclose(got, want, atol=2e-6)
        np.testing.assert_allclose(graph.origins[i], t, atol=1e-6)
    np.testing.assert_array_equal(
        graph.point_origins(), np.repeat(graph.origins, [50, 60, 70], axis=0)
    )


def test_text_log_is_the_same_graph() -> None:
    """``NODE x y z roll pitch yaw`` + points, as log2graph reads it: R = Rz Ry Rx."""
    rng = np.random.default_rng(2)
    rpy = [(0.0, 0.0, 0.0), (-0.2, 0.3, 1.2), (0.4, -0.1, -2.5)]
    lines = ["# a comment", ""]
    scans = []
    for i, (roll, pitch, yaw) in enumerate(rpy):
        pts, t = rng.uniform(-3, 3, (20 + i, 3)), rng.uniform(-5, 5, 3)
        lines.append(f"NODE {t[0]:.6f} {t[1]:.6f} {t[2]:.6f} {roll} {pitch} {yaw}")
        lines += [f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in pts]
        scans.append((np.round(pts, 6), np.round(t, 6), (roll, pitch, yaw)))
    graph = read_scan_log_bytes("\n".join(lines).encode())
    assert len(graph.origins) == 3 and graph.n_edges == 2
    for i, (pts, t, (roll, pitch, yaw)) in enumerate(scans):
        want = Rotation.from_euler("ZYX", [yaw, pitch, roll]).apply(pts) + t
        got = graph.points[graph.offsets[i] : graph.offsets[i + 1]]
        np.testing.assert_allclose(got, want, atol=2e-6)


def _small_graph() -> bytes:
    return write_scan_graph_bytes(_three_scans(np.random.default_rng(3))[:2])


def test_every_truncation_is_refused_by_name() -> None:
    data = _small_graph()
    nodes_end = len(data) - 4 - 80  # 2 nodes, then the edge count and one edge
    for cut in range(len(data)):
        if cut == nodes_end:  # no edge count at all: OctoMap reads no edges
            assert read_scan_graph_bytes(data[:cut]).n_edges == 0
            continue
        with pytest.raises(MapFormatError, match="truncated|fit|shorter|tagged"):
            read_scan_graph_bytes(data[:cut])
    with pytest.raises(MapFormatError, match="trailing"):
        read_scan_graph_bytes(data + b"\0")


def _patched(data: bytes, offset: int, fmt: str, *values: object) -> bytes:
    out = bytearray(data)
    struct.pack_into(fmt, out, offset, *values)
    return bytes(out)


@pytest.mark.parametrize(
    ("offset", "fmt", "values", "problem"),
    [
        (0, "<I", (0xFFFFFFFF,), "do not fit"),  # node count
        (4, "<I", (0xFFFFFFFF,), "points do not fit"),  # first node's point count
        (8, "<i", (2,), "not tagged 3"),  # a point's tag
        (8 + 28 * 50, "<i", (7,), "tagged 3 and 4"),  # the pose's translation tag
        (8 + 28 * 50 + 28 + 4, "<d", (2.0,), "norm"),  # quaternion w
        (8 + 28 * 50 + 4, "<d", (float("nan"),), "not finite"),  # translation x
    ],
)
def test_hostile_fields_are_refused_by_name(offset, fmt, values, problem) -> None:
    with pytest.raises(MapFormatError, match=problem):
        read_scan_graph_bytes(_patched(_small_graph(), offset, fmt, *values))


def test_edge_to_an_unknown_node_and_bad_logs_are_refused() -> None:
    data = _small_graph()
    with pytest.raises(MapFormatError, match="joins nodes 0 and 9"):
        read_scan_graph_bytes(_patched(data, len(data) - 80 + 4, "<I", 9))
    for text, problem in [
        (b"1 2 3\n", "before the first NODE"),
        (b"NODE 0 0 0 0 0\n1 2 3\n", "six numbers|roll pitch yaw"),
        (b"NODE 0 0 0 0 0 0\n1 x 3\n", "not numbers"),
        (b"NODE 0 0 0 0 0 0\n1 2 3\n# c\n\n4 y 6\n", "line 5: not numbers"),
        (b"NODE 0 0 0 0 0 0\n1 2\n", "x y z"),
        (b"# nothing\n", "no points"),
    ]:
        with pytest.raises(MapFormatError, match=problem):
            read_scan_log_bytes(text)


def test_file_errors_name_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.graph"
    bad.write_bytes(b"\x05\0\0\0")
    with pytest.raises(MapFormatError, match=r"bad\.graph: 5 nodes do not fit"):
        read_scan_graph(bad)
    big = tmp_path / "big.graph"
    big.write_bytes(_small_graph())
    with pytest.raises(MapFormatError, match=r"big\.graph: larger than 10 bytes"):
        read_scan_graph(big, max_bytes=10)


def test_the_writer_and_the_rotation_refuse_bad_scans_by_name() -> None:
    from secure3d.errors import GeometryError
    from secure3d.mapping.scan_graph import rotation_matrix

    ok = (np.zeros((2, 3)), np.zeros(3), np.array([1.0, 0, 0, 0]))
    for scan, problem in [
        ((np.zeros((2, 2)), ok[1], ok[2]), "points must be"),
        ((ok[0], np.zeros(2), ok[2]), "translation"),
        ((np.full((2, 3), np.nan), ok[1], ok[2]), "finite"),
        ((ok[0], ok[1], np.array([2.0, 0, 0, 0])), "unit quaternion"),
    ]:
        with pytest.raises(GeometryError, match=problem):
            write_scan_graph_bytes([ok, scan])
    with pytest.raises(GeometryError, match="unit quaternion"):
        rotation_matrix(np.array([1.0, 0.0, 0.0]))
