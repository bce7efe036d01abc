"""OctoMap .bt/.ot files: real data against octomap-python, round trips, hostile input, fuzzing."""

from __future__ import annotations

import numpy as np
import octomap
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from secure3d.errors import MapFormatError
from secure3d.mapping import OccupancyMap
from secure3d.mapping.octomap_io import (
    BT_MAGIC,
    OT_MAGIC,
    read_bt_bytes,
    read_ot_bytes,
    read_scan_dat,
)

HEADER = b"# Octomap OcTree binary file\nid OcTree\nsize %d\nres %s\ndata\n"


@pytest.fixture(scope="module")
def geb079(octomap_dir) -> tuple[OccupancyMap, octomap.OcTree, bytes]:
    path = octomap_dir / "geb079.bt"
    tree = octomap.OcTree(0.1)
    assert tree.readBinary(str(path).encode())
    return OccupancyMap.read_bt(path), tree, path.read_bytes()


@pytest.fixture(scope="module")
def small_map(octomap_dir) -> OccupancyMap:
    """A small real map (a few KB as .bt): the seed for the fuzzer."""
    scan = read_scan_dat(octomap_dir / "scan.dat.bz2")
    m = OccupancyMap(0.2)
    m.insert_point_cloud(scan[::40], np.zeros(3), 2.5)
    return m


def octree_state_counts(tree: octomap.OcTree) -> tuple[int, int]:
    occ = free = 0
    for leaf in tree.begin_leafs():
        n = 8 ** (16 - leaf.getDepth())
        if tree.isNodeOccupied(leaf):
            occ += n
        else:
            free += n
    return occ, free


def test_geb079_same_voxels_as_octomap(geb079):
    ours, tree, _ = geb079
    assert ours.resolution == 0.08
    occ, free = ours.occupied_voxels(), ours.free_voxels()
    # Every voxel we call occupied/free is so for OctoMap, and the totals match: same sets.
    np.testing.assert_array_equal(tree.getLabels(occ), 1)
    np.testing.assert_array_equal(tree.getLabels(free), 0)
    assert octree_state_counts(tree) == (occ.shape[0], free.shape[0]) == (185_673, 950_759)
    # And unknown space agrees too, on random points around the building.
    rng = np.random.default_rng(0)
    pts = rng.uniform([-9.0, -8.5, -1.0], [32.0, 8.5, 3.5], size=(200_000, 3))
    np.testing.assert_array_equal(ours.classify(pts), tree.getLabels(pts))


def test_geb079_round_trip_is_byte_identical(geb079, tmp_path):
    ours, _, raw = geb079
    assert ours.to_bytes("bt") == raw
    out = tmp_path / "copy.bt"
    ours.write_bt(out)
    assert out.read_bytes() == raw
    assert [p.name for p in tmp_path.iterdir()] == ["copy.bt"], "no temporary file left behind"


def test_our_files_read_by_octomap_and_back(small_map, tmp_path, rng):
    pts = np.concatenate(
        [small_map.occupied_voxels(), small_map.free_voxels(), rng.uniform(-4, 4, (5000, 3))]
    )
    expected = small_map.classify(pts)
    bt, ot = tmp_path / "m.bt", tmp_path / "m.ot"
    small_map.write_bt(bt)
    small_map.write_ot(ot)
    tree_bt = octomap.OcTree(0.1)
    assert tree_bt.readBinary(str(bt).encode())
    np.testing.assert_array_equal(tree_bt.getLabels(pts), expected)
    tree_ot = octomap.OcTree.read(str(ot).encode())
    np.testing.assert_array_equal(tree_ot.getLabels(pts), expected)
    # .ot keeps log-odds: reading it back reproduces the file exactly.
    assert OccupancyMap.read_ot(ot).to_bytes("ot") == ot.read_bytes()
    # OctoMap's own files read by us.
    ref_bt, ref_ot = tmp_path / "ref.bt", tmp_path / "ref.ot"
    assert tree_ot.writeBinary(str(ref_bt).encode())
    tree_ot2 = octomap.OcTree.read(str(ot).encode())
    assert tree_ot2.write(str(ref_ot).encode())
    np.testing.assert_array_equal(OccupancyMap.read_bt(ref_bt).classify(pts), expected)
    np.testing.assert_array_equal(OccupancyMap.read_ot(ref_ot).classify(pts), expected)


def test_bt_keeps_only_the_binary_state(small_map):
    back = OccupancyMap.from_bytes(small_map.to_bytes("bt"))
    _, _, logodds = back.leaves()
    p = back.params
    assert set(np.unique(logodds)) <= {p.clamp_min_log, p.clamp_max_log}


def test_updates_split_pruned_leaves_like_octomap(geb079, tmp_path):
    """Inserting into a map read from .bt expands pruned leaves exactly as OctoMap does."""
    ours, _, raw = geb079
    ours = ours.copy()
    tree = octomap.OcTree(0.1)
    path = tmp_path / "geb079_copy.bt"
    path.write_bytes(raw)
    assert tree.readBinary(str(path).encode())
    rng = np.random.default_rng(1)
    origin = np.array([2.0, 0.0, 1.0])
    cloud = origin + rng.normal(0, 3.0, size=(3000, 3))
    ours.insert_point_cloud(cloud, origin, 4.0)
    tree.insertPointCloud(cloud, origin, maxrange=4.0)
    assert ours.to_bytes("ot") == tree.write()


def test_flipped_leaf_states_read_like_octomap(geb079, tmp_path):
    """Swap free <-> occupied leaves in random geb079 records (structure intact): same labels."""
    ours, _, raw = geb079
    start = raw.index(b"\ndata\n") + len(b"\ndata\n")
    body = np.frombuffer(raw, np.uint8, offset=start).copy()
    rng = np.random.default_rng(3)
    picked = 2 * rng.choice(body.size // 2, size=2000, replace=False)
    for offset in (0, 1):
        byte = body[picked + offset]
        for child in range(4):
            code = (byte >> (2 * child)) & 3
            byte = np.where((code == 1) | (code == 2), byte ^ (3 << (2 * child)), byte)
        body[picked + offset] = byte
    data = raw[:start] + body.tobytes()
    path = tmp_path / "flipped.bt"
    path.write_bytes(data)
    tree = octomap.OcTree(0.1)
    assert tree.readBinary(str(path).encode())
    flipped = OccupancyMap.from_bytes(data)
    pts = np.concatenate([ours.occupied_voxels(), ours.free_voxels()[::10]])
    labels = flipped.classify(pts)
    np.testing.assert_array_equal(labels, tree.getLabels(pts))
    assert (labels != ours.classify(pts)).sum() > 1000, "the flips changed many voxels"


def bt(size: int, res: str, body: bytes) -> bytes:
    return HEADER % (size, res.encode()) + body


# Two inner levels down to one occupied voxel: root -> child 0 (inner) ... 16 levels in total.
CHAIN = b"\x03\x00" * 15 + b"\x02\x00"
CHAIN_SIZE = 1 + 15 + 1


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"", "bad header"),
        (b"# Octomap OcTree file\nid OcTree\nsize 0\nres 0.1\ndata\n", "bad header"),
        (b"# Octomap OcTree binary file\nid OcTree\nsize 1\nres 0.1\n", "no 'data' line"),
        (b"# Octomap OcTree binary file\n" + b"#" * 10_000 + b"\ndata\n", "no 'data' line"),
        (b"# Octomap OcTree file\nid CountingOcTree\nsize 0\nres 0.1\ndata\n", "tree type"),
        (b"# Octomap OcTree binary file\nsize 0\nres 0.1\ndata\n", "missing 'id'"),
        (b"# Octomap OcTree binary file\nid OcTree\nsize x\nres 0.1\ndata\n", "not an integer"),
        (b"# Octomap OcTree binary file\nid OcTree\nsize 0\nres 0.1\nres 0.2\ndata\n", "duplicate"),
        (b"# Octomap OcTree binary file\nid OcTree\nsize 0\nres \xff\ndata\n", "non-ASCII"),
        (bt(0, "0", b""), "res must be finite and > 0"),
        (bt(0, "-0.1", b""), "res must be finite and > 0"),
        (bt(0, "nan", b""), "res must be finite and > 0"),
        (bt(0, "inf", b""), "res must be finite and > 0"),
        (bt(0, "abc", b""), "not a number"),
        (bt(-3, "0.1", b""), "negative size"),
        (bt(10**15, "0.1", CHAIN), "impossible"),
        (bt(CHAIN_SIZE + 1, "0.1", CHAIN), "size mismatch"),
        (bt(CHAIN_SIZE - 1, "0.1", CHAIN), "more nodes than the header's size"),
        (bt(CHAIN_SIZE, "0.1", CHAIN + b"\n"), "trailing bytes"),
        (bt(0, "0.1", b"\x00\x00"), "data bytes follow"),
        (bt(CHAIN_SIZE, "0.1", CHAIN[:-2]), "truncated"),
        (bt(CHAIN_SIZE, "0.1", CHAIN[:-1]), "truncated"),
        (bt(18, "0.1", b"\x03\x00" * 16 + b"\x02\x00"), "deeper than OctoMap's 16 levels"),
        (bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8)), "header"),
    ],
)
def test_hostile_bt_raises_with_reason(data, reason):
    with pytest.raises(MapFormatError, match=reason):
        read_bt_bytes(data)
    if not data.startswith(OT_MAGIC):  # a valid .ot header is fine for from_bytes
        with pytest.raises(MapFormatError, match=reason):
            OccupancyMap.from_bytes(data)


def test_valid_chain_and_degenerate_trees_match_octomap(tmp_path):
    """Hand-made corner cases that OctoMap accepts: we read them the same way."""
    cases = {
        "chain": bt(CHAIN_SIZE, "0.1", CHAIN),
        # A childless root is a leaf that OctoMap leaves at its default: occupied everywhere.
        "empty_root": bt(1, "0.1", b"\x00\x00"),
        # An inner child without children becomes a free leaf (log-odds -FLT_MAX) in OctoMap.
        "childless_inner": bt(2, "0.1", b"\xc0\x00\x00\x00"),
        "empty": bt(0, "0.1", b""),
    }
    probes = np.array([[0.05, 0.05, 0.05], [-0.05, -0.05, -0.05], [100.0, -3.0, 7.0]])
    for name, data in cases.items():
        path = tmp_path / f"{name}.bt"
        path.write_bytes(data)
        tree = octomap.OcTree(0.1)
        assert tree.readBinary(str(path).encode()), name
        ours = OccupancyMap.from_bytes(data)
        np.testing.assert_array_equal(ours.classify(probes), tree.getLabels(probes), err_msg=name)
        assert OccupancyMap.from_bytes(ours.to_bytes("bt")).to_bytes("bt") == ours.to_bytes("bt")


@pytest.mark.parametrize(
    ("mutate", "reason"),
    [
        (lambda d: d[:-3], "truncated"),
        (lambda d: d + b"\x00", "trailing bytes"),
        (lambda d: d.replace(b"size ", b"size 1"), "size"),
        (lambda d: d.replace(b"res 0.2", b"res 0"), "res must be finite"),
    ],
)
def test_hostile_ot_raises_with_reason(small_map, mutate, reason):
    with pytest.raises(MapFormatError, match=reason):
        OccupancyMap.from_bytes(mutate(small_map.to_bytes("ot")))


def test_ot_rejects_non_finite_log_odds():
    body = np.array([np.nan], "<f4").tobytes() + b"\x00"
    data = b"# Octomap OcTree file\nid OcTree\nsize 1\nres 0.1\ndata\n" + body
    with pytest.raises(MapFormatError, match="non-finite"):
        read_ot_bytes(data)


def test_read_file_errors(tmp_path):
    with pytest.raises(OSError):
        OccupancyMap.read_bt(tmp_path / "missing.bt")
    with pytest.raises(MapFormatError, match="non-numeric"):
        (tmp_path / "bad.dat").write_text("1 2 three\n")
        read_scan_dat(tmp_path / "bad.dat")
    (tmp_path / "odd.dat").write_text("1 2 3 4\n")
    with pytest.raises(MapFormatError, match="multiple of 3"):
        read_scan_dat(tmp_path / "odd.dat")


mutation = st.one_of(
    st.tuples(st.just("flip"), st.integers(0, 10**6), st.integers(1, 255)),
    st.tuples(st.just("cut"), st.integers(0, 10**6), st.just(0)),
    st.tuples(st.just("insert"), st.integers(0, 10**6), st.integers(0, 255)),
    st.tuples(st.just("delete"), st.integers(0, 10**6), st.integers(1, 16)),
)


def apply(data: bytes, ops: list[tuple[str, int, int]]) -> bytes:
    buf = bytearray(data)
    for op, pos, arg in ops:
        if not buf:
            break
        i = pos % len(buf)
        if op == "flip":
            buf[i] ^= arg
        elif op == "cut":
            del buf[i:]
        elif op == "insert":
            buf.insert(i, arg)
        else:
            del buf[i : i + arg]
    return bytes(buf)


@settings(
    max_examples=250,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(fmt=st.sampled_from(["bt", "ot"]), ops=st.lists(mutation, min_size=1, max_size=4))
def test_fuzz_reader_never_crashes_or_misreads(small_map, tmp_path, fmt, ops):
    """Mutated real files either raise MapFormatError or give a map that OctoMap reads alike."""
    data = apply(small_map.to_bytes(fmt), ops)
    try:
        ours = OccupancyMap.from_bytes(data)
    except MapFormatError:
        return
    probes = np.random.default_rng(len(data)).uniform(-4, 4, size=(300, 3))
    labels = ours.classify(probes)
    again = OccupancyMap.from_bytes(ours.to_bytes(fmt))
    np.testing.assert_array_equal(again.classify(probes), labels)
    if data.startswith(BT_MAGIC):
        # Differential check: files we accept are well-formed, so OctoMap can read them too.
        path = tmp_path / "fuzz.bt"
        path.write_bytes(data)
        tree = octomap.OcTree(0.1)
        if tree.readBinary(str(path).encode()):
            ref = OccupancyMap.from_bytes(data)
            np.testing.assert_array_equal(ref.classify(probes), tree.getLabels(probes))


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=600))
def test_fuzz_random_bytes_after_a_valid_header(body):
    for data in (HEADER % (len(body) // 2 + 1, b"0.1") + body, BT_MAGIC + b"\n" + body):
        try:
            leaves = read_bt_bytes(data)
        except MapFormatError:
            continue
        assert leaves.starts.size == leaves.depths.size == leaves.values.size
        assert np.all(np.diff(leaves.starts) > 0), "leaves sorted and distinct"
