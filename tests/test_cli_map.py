"""``secure3d map info|convert`` on real files: OctoMap (colour trees too), clouds, meshes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import octomap
import pytest

from secure3d._deps import open3d
from secure3d.cli import main
from secure3d.mapping import OccupancyMap
from secure3d.world import load_scenario
from secure3d.world.attacks import belief_map

MAPS = Path(__file__).resolve().parents[1] / "maps"


@pytest.fixture
def colour_ot(tmp_path: Path) -> Path:
    rng = np.random.default_rng(2)
    pts = rng.uniform(-1.0, 1.0, (800, 3))
    tree = octomap.ColorOcTree(0.1)
    tree.insertPointCloud(pts, np.zeros(3))
    for p in pts:
        tree.setNodeColor(p, 200, 30, 40)
    path = tmp_path / "colour.ot"
    assert tree.write(str(path).encode())
    return path


def test_info_of_a_colour_tree(colour_ot: Path, capsys) -> None:
    assert main(["map", "info", str(colour_ot)]) == 0
    out = capsys.readouterr().out
    assert "tree type ColorOcTree" in out and "colour     : yes" in out
    ref = OccupancyMap.read_ot(colour_ot)
    assert f"occupied   : {len(ref.occupied_voxels())} voxels" in out


def test_convert_cloud_to_bt_is_the_server_claim(tmp_path: Path, capsys) -> None:
    out = tmp_path / "scan.bt"
    args = ["map", "convert", str(MAPS / "clouds" / "blind_corner_scan.ply"), str(out)]
    assert main([*args, "--resolution", "0.1", "--origin", "6.75", "1.25", "1.25"]) == 0
    claim = belief_map(load_scenario(MAPS / "cloud_server.yaml"))
    m = OccupancyMap.read_bt(out)
    np.testing.assert_array_equal(
        np.sort(m.occupied_voxels(), 0), np.sort(claim.claimed_voxels(True), 0)
    )
    # and OctoMap reads the file
    tree = octomap.OcTree(0.1)
    assert tree.readBinary(str(out).encode())
    np.testing.assert_array_equal(tree.getLabels(m.occupied_voxels()), 1)


def test_convert_octomap_back_to_a_coloured_cloud(colour_ot: Path, tmp_path: Path) -> None:
    out = tmp_path / "voxels.ply"
    assert main(["map", "convert", str(colour_ot), str(out)]) == 0
    pcd = open3d().io.read_point_cloud(str(out))
    pts = np.asarray(pcd.points)
    ref = OccupancyMap.read_ot(colour_ot).occupied_voxels()
    np.testing.assert_allclose(np.sort(pts, 0), np.sort(ref, 0), atol=1e-9)
    assert pcd.has_colors()


def test_convert_mesh_to_ot(tmp_path: Path) -> None:
    out = tmp_path / "b.ot"
    src = MAPS / "meshes" / "blind_corner_building.obj"
    assert main(["map", "convert", str(src), str(out), "--resolution", "0.1"]) == 0
    claim = belief_map(load_scenario(MAPS / "mesh_server.yaml"))
    assert len(OccupancyMap.read_ot(out).occupied_voxels()) == len(claim.claimed_voxels(True))


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["map", "info", "missing.bt"], "cannot read"),
        (["map", "info", "/dev/zero"], "unknown map file type '(no suffix)'"),
        (["map", "info", "notes.txt"], "point clouds (.ply, .pcd, .xyz, .dat, .dat.bz2)"),
        (["map", "convert", "notes.txt", "x.bt", "--resolution", "0.1"], "unknown map file"),
        (["map", "convert", "scan.ply", "x.bt"], "--resolution"),
        (["map", "convert", str(MAPS / "octomaps" / "office_server.bt"), "x.obj"], "converts to"),
    ],
)
def test_errors_are_one_line(argv, message, capsys, tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "scan.ply").write_bytes((MAPS / "clouds" / "blind_corner_scan.ply").read_bytes())
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err and err.startswith("secure3d: error: ")


def test_info_and_convert_of_octomaps_point_file(octomap_dir: Path, tmp_path: Path, capsys) -> None:
    """OctoMap's scan.dat.bz2 (a compressed x y z point file): described, and converted with
    rays from --origin as octomap-python inserts the same points."""
    src = octomap_dir / "scan.dat.bz2"
    assert main(["map", "info", str(src)]) == 0
    assert "point cloud, 88206 points" in capsys.readouterr().out
    dst = tmp_path / "scan.bt"
    args = ["map", "convert", str(src), str(dst), "--resolution", "0.2", "--origin", "0", "0", "0"]
    assert main(args) == 0
    from secure3d.mapping.octomap_io import read_scan_dat

    tree = octomap.OcTree(0.2)
    tree.insertPointCloud(read_scan_dat(src), np.zeros(3))
    m = OccupancyMap.read_bt(dst)
    np.testing.assert_array_equal(tree.getLabels(m.occupied_voxels()), 1)
    np.testing.assert_array_equal(tree.getLabels(m.free_voxels()), 0)
    assert len(m.occupied_voxels()) > 5_000 and len(m.free_voxels()) > 50_000


def test_info_and_convert_of_octomaps_scan_graph(octomap_dir: Path, tmp_path: Path, capsys) -> None:
    """OctoMap's spherical_scan.graph: described, and converted as graph2tree builds it."""
    src = octomap_dir / "spherical_scan.graph"
    assert main(["map", "info", str(src)]) == 0
    out = capsys.readouterr().out
    assert "OctoMap scan graph, 1 scans, 10201 points" in out and "(1, 0, -0.5)" in out
    dst = tmp_path / "sphere.bt"
    assert main(["map", "convert", str(src), str(dst), "--resolution", "0.1"]) == 0
    m = OccupancyMap.read_bt(dst)
    from secure3d.mapping.scan_graph import read_scan_graph

    g = read_scan_graph(src)
    tree = octomap.OcTree(0.1)
    tree.insertPointCloud(g.points, g.origins[0])
    tree.updateInnerOccupancy()
    np.testing.assert_array_equal(tree.getLabels(m.occupied_voxels()), 1)
    np.testing.assert_array_equal(tree.getLabels(m.free_voxels()), 0)
    assert len(m.occupied_voxels()) > 1000 and len(m.free_voxels()) > 10_000
