"""Every occupancy file OctoMap reads: .bt of any tree id, the legacy binary header, .ot of OcTree,
OcTreeStamped and ColorOcTree. Leaves are compared exactly with octomap-python's."""

from __future__ import annotations

import struct

import numpy as np
import octomap
import pytest

from secure3d.errors import MapFormatError
from secure3d.mapping import OccupancyMap
from secure3d.mapping.keys import morton_decode
from secure3d.mapping.octomap_io import read_octomap_bytes, read_octomap_file


@pytest.fixture(scope="module")
def cloud() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    pts = rng.uniform(-2.0, 2.0, (1500, 3))
    return pts, np.zeros(3)


def reference_leaves(tree, colors: bool = False) -> dict:
    """octomap-python's leaves: {(kx, ky, kz, depth): (log-odds, (r, g, b) or None)}."""
    out = {}
    for leaf in tree.begin_leafs():
        k = leaf.getIndexKey()
        color = tuple(leaf.getColor()) if colors else None
        out[(k[0], k[1], k[2], leaf.getDepth())] = (np.float32(leaf.getValue()), color)
    return out


def our_leaves(leaves) -> dict:
    keys = morton_decode(leaves.starts)
    out = {}
    for i, (k, d) in enumerate(zip(keys, leaves.depths, strict=True)):
        color = tuple(int(c) for c in leaves.colors[i]) if leaves.colors is not None else None
        out[(int(k[0]), int(k[1]), int(k[2]), int(d))] = (leaves.values[i], color)
    return out


def with_id(data: bytes, tree_id: bytes) -> bytes:
    head, _, rest = data.partition(b"\nid ")
    _, _, rest = rest.partition(b"\n")
    return head + b"\nid " + tree_id + b"\n" + rest


@pytest.mark.parametrize(
    "tree_id", [b"OcTree", b"ColorOcTree", b"OcTreeStamped", b"SemanticOcTree", b"1"]
)
def test_bt_of_every_tree_id_matches_octomap(cloud, tmp_path, tree_id):
    """OctoMap's readBinary ignores the id (a .bt is occupancy bits only): the leaves agree."""
    tree = octomap.ColorOcTree(0.1) if tree_id == b"ColorOcTree" else octomap.OcTree(0.1)
    tree.insertPointCloud(*cloud)
    path = tmp_path / "m.bt"
    assert tree.writeBinary(str(path).encode())
    data = with_id(path.read_bytes(), tree_id)
    assert (b"\nid " + tree_id + b"\n") in data
    path.write_bytes(data)
    ref = octomap.OcTree(0.1)
    assert ref.readBinary(str(path).encode())
    expected = {k: (v >= 0, c) for k, (v, c) in reference_leaves(ref).items()}
    leaves = read_octomap_file(path)
    assert leaves.fmt == "bt" and leaves.colors is None
    got = {k: (v > 0, c) for k, (v, c) in our_leaves(leaves).items()}
    assert got == expected and len(got) > 1000
    assert leaves.tree_id == ("OcTree" if tree_id == b"1" else tree_id.decode())


def test_legacy_binary_header_matches_octomap(cloud, tmp_path):
    tree = octomap.OcTree(0.1)
    tree.insertPointCloud(*cloud)
    path = tmp_path / "m.bt"
    assert tree.writeBinary(str(path).encode())
    raw = path.read_bytes()
    body = raw[raw.index(b"\ndata\n") + len(b"\ndata\n") :]
    legacy = tmp_path / "legacy.bt"
    legacy.write_bytes(struct.pack("<idI", 3, 0.1, tree.size()) + body)
    ref = octomap.OcTree(0.1)
    assert ref.readBinary(str(legacy).encode())
    got = {k: (v > 0, c) for k, (v, c) in our_leaves(read_octomap_file(legacy)).items()}
    assert got == {k: (v >= 0, c) for k, (v, c) in reference_leaves(ref).items()}
    # Same tree as the text-header file, and an OccupancyMap reads it too.
    assert OccupancyMap.read_bt(legacy).to_bytes("bt") == OccupancyMap.read_bt(path).to_bytes("bt")
    with pytest.raises(MapFormatError, match="res"):
        read_octomap_bytes(struct.pack("<idI", 3, -0.1, 1) + b"\x00\x00")


@pytest.mark.parametrize("tree_id", ["OcTree", "OcTreeStamped"])
def test_ot_of_plain_and_stamped_trees_matches_octomap(cloud, tmp_path, tree_id):
    tree = octomap.OcTree(0.1)
    tree.insertPointCloud(*cloud)
    data = with_id(tree.write(), tree_id.encode())  # OcTreeStamped's node layout is OcTree's
    path = tmp_path / "m.ot"
    path.write_bytes(data)
    ref = octomap.OcTree.read(str(path).encode())
    assert ref.getTreeType() == tree_id.encode()
    leaves = read_octomap_file(path)
    assert leaves.fmt == "ot" and leaves.tree_id == tree_id and leaves.colors is None
    assert our_leaves(leaves) == reference_leaves(ref)
    # log-odds kept exactly
    assert OccupancyMap.read_ot(path).to_bytes("ot") == with_id(data, b"OcTree")


def test_colour_ot_matches_octomap_with_colours(cloud, tmp_path):
    tree = octomap.ColorOcTree(0.1)
    tree.insertPointCloud(*cloud)
    rng = np.random.default_rng(3)
    for p in cloud[0][:300]:
        tree.setNodeColor(p, *(int(c) for c in rng.integers(0, 256, 3)))
    path = tmp_path / "c.ot"
    assert tree.write(str(path).encode())
    assert b"\nid ColorOcTree\n" in path.read_bytes()[:200]
    ref = octomap.ColorOcTree.read(str(path).encode())
    leaves = read_octomap_file(path)
    assert leaves.tree_id == "ColorOcTree" and leaves.colors.shape == (leaves.starts.size, 3)
    expected = reference_leaves(ref, colors=True)
    assert our_leaves(leaves) == expected
    assert len({c for _, c in expected.values()}) > 100, "many distinct colours compared"


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"# Octomap OcTree file\nid CountingOcTree\nsize 0\nres 0.1\ndata\n", "tree type"),
        (b"# Octomap OcTree file\nid MyTree\nsize 0\nres 0.1\ndata\n", "tree type"),
        (b"# Octomap OcTree binary file\nid OcTree\nsize 0\nres 1e300\ndata\n", "outside"),
        (b"# Octomap OcTree binary file\nid OcTree\nsize 0\nres 1e-9\ndata\n", "outside"),
        (b"# Octomap OcTree binary file\nid OcTree\nsize 0\nres -1\ndata\n", "finite and > 0"),
        (b"# Octomap OcTree binary file\nid OcTree\nsize 0\nres nan\ndata\n", "finite and > 0"),
        (b"# Octomap OcTree file\nid ColorOcTree\nsize 1\nres 0.1\ndata\n" + b"\0" * 5, "size"),
    ],
)
def test_files_octomap_or_we_refuse_raise_one_line(data, reason):
    with pytest.raises(MapFormatError, match=reason) as err:
        read_octomap_bytes(data)
    assert "\n" not in str(err.value)


def test_dev_zero_is_refused_after_a_few_kb(monkeypatch):
    """Header first: /dev/zero (endless, size 0 by stat) is refused after one 4 KB read; the
    reader never even asks for more than 64 KB (the old reader asked for 1 GiB + 1)."""
    import pathlib

    asked: list[int] = []
    real_open = pathlib.Path.open

    class Counting:
        def __init__(self, fh):
            self.fh = fh

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

        def read(self, n=-1):
            asked.append(n)
            if n < 0 or n > 65536:
                raise AssertionError(f"asked for {n} bytes of /dev/zero")
            return self.fh.read(n)

    def counting_open(self, mode="r", *args, **kwargs):
        fh = real_open(self, mode, *args, **kwargs)
        return Counting(fh) if str(self) == "/dev/zero" else fh

    monkeypatch.setattr(pathlib.Path, "open", counting_open)
    with pytest.raises(MapFormatError, match="not an OctoMap file"):
        OccupancyMap.read_bt("/dev/zero")
    assert 0 < sum(asked) <= 8192


def test_bounded_read_stops_at_what_the_header_allows(cloud, tmp_path):
    """A valid header followed by far more bytes than its size allows: refused, and the reader
    never reads the excess (one byte more than valid)."""
    tree = octomap.OcTree(0.1)
    tree.insertPointCloud(*cloud)
    data = tree.write()
    path = tmp_path / "padded.ot"
    path.write_bytes(data + b"\0" * 5_000_000)
    from secure3d.mapping.octomap_header import read_file_bounded

    assert len(read_file_bounded(path)) == len(data) + 1
    with pytest.raises(MapFormatError, match="1 trailing bytes"):
        read_octomap_file(path)
