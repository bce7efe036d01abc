"""Server maps from files (OctoMap of any type, point cloud, mesh), region attacks, and the
region-attack campaign family."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml

from secure3d.errors import ScenarioError
from secure3d.mapping import OccupancyMap
from secure3d.world import load_scenario, save_scenario
from secure3d.world.attacks import belief_map, octomap_voxel_boxes
from secure3d.world.region_attacks import REGION_ATTACKS, variant_rng
from secure3d.world.server_sources import read_cloud, surface_voxel_centres
from secure3d.world.spec import Attack, Region, ServerMapSpec

MAPS = Path(__file__).resolve().parents[2] / "maps"


@pytest.fixture
def office(tmp_path: Path) -> Path:
    """office_bt.yaml and its two OctoMaps in a scratch folder."""
    (tmp_path / "octomaps").mkdir()
    for name in ("office_truth.bt", "office_server.bt"):
        (tmp_path / "octomaps" / name).write_bytes((MAPS / "octomaps" / name).read_bytes())
    (tmp_path / "office_bt.yaml").write_text((MAPS / "office_bt.yaml").read_text())
    return tmp_path


def _edit(folder: Path, change) -> Path:
    data = yaml.safe_load((folder / "office_bt.yaml").read_text())
    change(data)
    path = folder / "edited.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def _claims(belief: OccupancyMap) -> tuple[set, set]:
    r = belief.resolution
    occ = {tuple(k) for k in np.floor(belief.claimed_voxels(True) / r).astype(int)}
    free = {tuple(k) for k in np.floor(belief.claimed_voxels(False) / r).astype(int)}
    return occ, free


def test_colour_tree_bt_and_ot_are_accepted_as_world_and_server_maps(office: Path) -> None:
    """The user's ColorOcTree scan (id line as OctoMap writes it) and .ot files load and give the
    same voxels as the plain .bt."""
    truth = office / "octomaps" / "office_truth.bt"
    raw = truth.read_bytes()
    (office / "octomaps" / "truth_color.bt").write_bytes(
        raw.replace(b"\nid OcTree\n", b"\nid ColorOcTree\n", 1)
    )
    OccupancyMap.read_bt(office / "octomaps" / "office_server.bt").write_ot(
        office / "octomaps" / "server.ot"
    )

    def change(d: dict) -> None:
        d["world"]["octomap"] = "octomaps/truth_color.bt"
        d["server_map"].pop("bt")
        d["server_map"]["octomap"] = "octomaps/server.ot"

    s = load_scenario(_edit(office, change))
    assert s.server_map.octomap.name == "server.ot"
    np.testing.assert_array_equal(octomap_voxel_boxes(s.world.octomap), octomap_voxel_boxes(truth))
    base = load_scenario(office / "office_bt.yaml")
    assert _claims(belief_map(s)) == _claims(belief_map(base))


def test_server_octomap_key_and_old_bt_key_are_the_same(office: Path) -> None:
    def rename(d: dict) -> None:
        d["server_map"]["octomap"] = d["server_map"].pop("bt")

    new = load_scenario(_edit(office, rename))
    old = load_scenario(office / "office_bt.yaml")
    assert new.server_map == old.server_map
    # written back with the new key, read back equal
    again = load_scenario(save_scenario(new, office / "saved.yaml"))
    assert "octomap:" in (office / "saved.yaml").read_text()
    assert again.server_map == new.server_map


def test_server_resolution_must_match_the_file(office: Path) -> None:
    def change(d: dict) -> None:
        d["server_map"]["resolution"] = 0.05

    with pytest.raises(ScenarioError, match=r"server_map\.resolution: differs from .* 0\.1 m") as e:
        load_scenario(_edit(office, change))
    assert "\n" not in str(e.value) and "edited.yaml" in str(e.value)


@pytest.mark.parametrize(
    ("attack", "field", "problem"),
    [
        ({"kind": "stale", "region": {"lo": [1, 1, 0], "hi": [2, 2, 1]}}, "kind", "hide, shift"),
        ({"kind": "hide", "region": {"lo": [1, 1, 0], "hi": [0, 2, 1]}}, "region.hi", "exceed"),
        ({"kind": "shift", "region": {"lo": [1, 1, 0], "hi": [2, 2, 1]}}, "by", "missing"),
        (
            {"kind": "hide", "region": {"lo": [1, 1, 0], "hi": [2, 2, 1]}, "target": "x"},
            "target",
            "unknown key",
        ),
        ({"kind": "hide", "region": {"lo": [50, 50, 0], "hi": [51, 51, 1]}}, "region", "outside"),
    ],
)
def test_bad_region_attacks_are_one_line_errors(office, attack, field, problem) -> None:
    def change(d: dict) -> None:
        d["server_map"]["attacks"] = [attack]

    with pytest.raises(ScenarioError, match=problem) as e:
        load_scenario(_edit(office, change))
    assert f"server_map.attacks[0].{field}" in str(e.value)
    assert "\n" not in str(e.value)


def test_named_attacks_need_a_world_derived_server_map() -> None:
    with pytest.raises(ScenarioError, match="only region attacks act on a server map given as"):
        ServerMapSpec(attacks=(Attack("hide", target="crate"),), cloud="scan.ply")
    ServerMapSpec(attacks=(Attack("hide", region=Region((0, 0, 0), (1, 1, 1))),), cloud="a.ply")


def test_region_attacks_edit_a_real_server_map(office: Path) -> None:
    """hide frees the region's claimed obstacles, shift moves them, phantom invents some; nothing
    outside the region (and its shifted copy) changes."""
    region = {"lo": [6.0, 0.0, 0.0], "hi": [9.5, 2.5, 1.5]}  # desk_b and part of the walls
    base = load_scenario(office / "office_bt.yaml")
    occ0, free0 = _claims(belief_map(base))
    lo, hi = np.array(region["lo"]) / 0.1, np.array(region["hi"]) / 0.1
    in_region = {k for k in occ0 if np.all(np.add(k, 0.5) >= lo) and np.all(np.add(k, 0.5) <= hi)}
    assert len(in_region) > 200

    def with_attack(attack: dict) -> OccupancyMap:
        def change(d: dict) -> None:
            d["server_map"]["attacks"] = [attack]

        return belief_map(load_scenario(_edit(office, change)))

    occ, free = _claims(with_attack({"kind": "hide", "region": region}))
    assert occ == occ0 - in_region and in_region <= free

    occ, free = _claims(with_attack({"kind": "shift", "region": region, "by": [0.0, 1.0, 0.0]}))
    moved = {(k[0], k[1] + 10, k[2]) for k in in_region}
    assert moved <= occ and occ == (occ0 - in_region) | moved
    assert (in_region - moved) <= free

    occ, _ = _claims(
        with_attack(
            {"kind": "phantom", "region": {"lo": [2.03, 3.03, 1.03], "hi": [2.97, 3.97, 1.97]}}
        )
    )
    box = {(x, y, z) for x in range(20, 30) for y in range(30, 40) for z in range(10, 20)}
    assert box <= occ and occ - box == occ0 - box


def test_region_attack_on_world_derived_map_and_round_trip(tmp_path: Path) -> None:
    s = load_scenario(MAPS / "blind_corner.yaml")
    attack = Attack("hide", region=Region((5.4, 2.4, 0.0), (8.1, 9.0, 2.5)))
    s2 = dataclasses.replace(
        s, server_map=dataclasses.replace(s.server_map, attacks=(*s.server_map.attacks, attack))
    )
    occ0, _ = _claims(belief_map(s))
    occ, free = _claims(belief_map(s2))
    assert occ < occ0 and free
    (tmp_path / "x.yaml").write_text("")
    back = load_scenario(save_scenario(s2, tmp_path / "x.yaml"))
    assert back.server_map.attacks == s2.server_map.attacks
    assert "hide region" in back.summary()


def test_cloud_server_map_is_octomap_rays_from_the_origin() -> None:
    s = load_scenario(MAPS / "cloud_server.yaml")
    points = read_cloud(s.server_map.cloud)
    ref = OccupancyMap(0.1)
    ref.insert_point_cloud(points, np.array(s.server_map.origin), None)
    occ, free = _claims(belief_map(s))
    r = 0.1
    assert occ == {tuple(k) for k in np.floor(ref.occupied_voxels() / r).astype(int)}
    assert free == {tuple(k) for k in np.floor(ref.free_voxels() / r).astype(int)}
    assert len(free) > 10_000
    # The crate (5.5..6.9, 3.6..4.4) is not in the scan: its inside is claimed free.
    assert (60, 40, 12) in free


def test_cloud_without_origin_claims_only_its_points(tmp_path: Path) -> None:
    data = yaml.safe_load((MAPS / "cloud_server.yaml").read_text())
    del data["server_map"]["origin"]
    (tmp_path / "clouds").mkdir()
    (tmp_path / "clouds" / "blind_corner_scan.ply").write_bytes(
        (MAPS / "clouds" / "blind_corner_scan.ply").read_bytes()
    )
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    s = load_scenario(tmp_path / "s.yaml")
    occ, free = _claims(belief_map(s))
    pts = read_cloud(s.server_map.cloud)
    assert not free
    assert occ == {tuple(k) for k in np.floor(pts / 0.1).astype(int)}


def test_mesh_surface_voxels_cover_the_surface_and_nothing_far() -> None:
    lo, hi = np.array([0.33, -0.21, 1.07]), np.array([1.47, 0.58, 1.93])
    mesh = trimesh.creation.box(extents=hi - lo)
    mesh.apply_translation(0.5 * (lo + hi))
    res = 0.1
    centres = surface_voxel_centres(np.asarray(mesh.vertices), np.asarray(mesh.faces), res)
    keys = {tuple(k) for k in np.floor(centres / res).astype(int)}
    samples, _ = trimesh.sample.sample_surface(mesh, 20_000, seed=1)
    touched = {tuple(k) for k in np.floor(samples / res).astype(int)}
    assert touched <= keys
    # unsigned distance of each centre to the box's surface, analytically
    outside = np.linalg.norm(np.maximum(np.maximum(lo - centres, centres - hi), 0), axis=1)
    inside = np.min(np.minimum(centres - lo, hi - centres), axis=1)
    dist = np.where(outside > 0, outside, inside)
    assert np.all(dist <= 0.5 * np.sqrt(3) * res + 1e-6)
    # the inside of the box is not claimed (a surface, not a solid)
    assert tuple(np.floor(0.5 * (lo + hi) / res).astype(int)) not in keys


def test_mesh_server_map_claims_the_building_surface() -> None:
    s = load_scenario(MAPS / "mesh_server.yaml")
    occ, free = _claims(belief_map(s))
    assert not free and len(occ) > 10_000
    # a wall surface voxel is claimed; the hidden crate's inside is not
    assert (84, 50, 12) in occ and (60, 40, 12) not in occ


@pytest.mark.slow
def test_region_attack_family_is_pure_and_valid() -> None:
    base = load_scenario(MAPS / "geb079_region_attacks.yaml")
    prep = REGION_ATTACKS.prepare(base)
    variants = [REGION_ATTACKS.variant(prep, base, variant_rng(7, i), i) for i in range(12)]
    again = REGION_ATTACKS.variant(REGION_ATTACKS.prepare(base), base, variant_rng(7, 5), 5)
    assert again == variants[5]
    kinds = {v.server_map.attacks[-1].kind for v in variants}
    assert kinds <= {"hide", "shift", "phantom"} and len(kinds) >= 2
    assert len({v.name for v in variants}) == 12
    occ0, _ = _claims(belief_map(base))
    for v in variants:
        assert v.server_map.attacks[-1].region is not None
        occ, _ = _claims(belief_map(v))
        assert occ != occ0, f"{v.name}: the attack changed nothing"


def test_cloud_with_per_point_origins_is_one_octomap_scan_per_origin(
    tmp_path: Path, octomap_voxels
) -> None:
    """A .ply with origin_x/y/z vertex properties: each point is a ray from its own origin, as
    octomap-python inserts each scan; the scenario's origin is not needed."""
    import octomap

    rng = np.random.default_rng(4)
    origins = np.array([[1.0, 1.0, 1.0], [6.75, 1.25, 1.25]])
    pts = np.vstack([o + rng.uniform(-2.5, 2.5, (400, 3)) for o in origins])
    own = np.repeat(origins, 400, axis=0)
    rows = "\n".join(" ".join(f"{v:.6f}" for v in (*p, *o)) for p, o in zip(pts, own, strict=True))
    props = "".join(
        f"property float {n}\n" for n in ("x", "y", "z", "origin_x", "origin_y", "origin_z")
    )
    (tmp_path / "clouds").mkdir()
    (tmp_path / "clouds" / "scans.ply").write_text(
        f"ply\nformat ascii 1.0\nelement vertex {len(pts)}\n{props}end_header\n{rows}\n"
    )
    data = yaml.safe_load((MAPS / "cloud_server.yaml").read_text())
    data["server_map"] = {"resolution": 0.1, "cloud": "clouds/scans.ply"}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    occ, free = _claims(belief_map(load_scenario(tmp_path / "s.yaml")))
    tree = octomap.OcTree(0.1)
    f32 = pts.astype(np.float32).astype(float)  # the file stores float32
    for o in origins:
        tree.insertPointCloud(f32[(own == o).all(1)], o)
    assert (len(occ), len(free)) == octomap_voxels(tree) and len(free) > 1000
    centre = lambda keys: (np.array(sorted(keys)) + 0.5) * 0.1  # noqa: E731
    np.testing.assert_array_equal(tree.getLabels(centre(occ)), 1)
    np.testing.assert_array_equal(tree.getLabels(centre(free)), 0)


def test_scan_graph_server_map_is_each_scan_from_its_pose_as_graph2tree_inserts_it(
    octomap_voxels,
) -> None:
    """warehouse_survey.yaml: four posed scans (yawed and tilted) of an OctoMap .graph; the claim
    is every scan inserted from its node's position in file order, voxel for voxel what
    octomap-python builds from the same world-frame points."""
    import octomap

    from secure3d.mapping.scan_graph import read_scan_graph

    s = load_scenario(MAPS / "warehouse_survey.yaml")
    graph = read_scan_graph(s.server_map.cloud)
    assert len(graph.origins) == 4 and not np.allclose(graph.rotations[1:], [1, 0, 0, 0])
    occ, free = _claims(belief_map(s))
    tree = octomap.OcTree(0.1)
    for k, o in enumerate(graph.origins):
        tree.insertPointCloud(graph.points[graph.offsets[k] : graph.offsets[k + 1]], o)
    assert (len(occ), len(free)) == octomap_voxels(tree) and len(free) > 50_000
    centre = lambda keys: (np.array(sorted(keys)) + 0.5) * 0.1  # noqa: E731
    np.testing.assert_array_equal(tree.getLabels(centre(occ)), 1)
    np.testing.assert_array_equal(tree.getLabels(centre(free)), 0)
    # The survey predates the barrel (12.97..13.93, 5.87..6.83, below 1.44 m): its place is claimed
    # free, and shelf_3 (y 8.0..8.8 today) is claimed where it stood, its face 0.6 m further
    # north: today's shelf in front of that face is claimed free.
    assert (134, 63, 7) in free
    assert (80, 86, 10) in occ and {(80, 80, 10), (80, 85, 10)} <= free


def test_a_broken_scan_graph_is_a_one_line_scenario_error(tmp_path: Path) -> None:
    data = yaml.safe_load((MAPS / "warehouse_survey.yaml").read_text())
    (tmp_path / "clouds").mkdir()
    (tmp_path / "meshes").mkdir()
    for name in ("crate_stack.obj", "barrel.ply"):
        (tmp_path / "meshes" / name).write_bytes((MAPS / "meshes" / name).read_bytes())
    raw = (MAPS / "clouds" / "warehouse_survey.graph").read_bytes()
    (tmp_path / "clouds" / "warehouse_survey.graph").write_bytes(raw[:-200])
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(
        ScenarioError, match=r"server_map.cloud: .*warehouse_survey\.graph: .*trunc"
    ):
        load_scenario(tmp_path / "s.yaml")


@pytest.mark.parametrize(
    ("name", "advice"),
    [
        ("scans.graph", r"'scans.graph' is a scan graph, not a tree.*convert scans.graph scans.bt"),
        (
            "scan.dat.bz2",
            r"'scan.dat.bz2' is a point cloud, not a tree.*scan.dat.bz2 scan.bt .*--origin X Y Z",
        ),
    ],
)
def test_a_scan_graph_or_cloud_as_the_true_world_says_how_to_make_a_tree(
    tmp_path: Path, name: str, advice: str
) -> None:
    (tmp_path / name).write_bytes((MAPS / "clouds" / "warehouse_survey.graph").read_bytes())
    data = {
        "name": "s",
        "world": {"bounds": {"lo": [0, 0, 0], "hi": [16, 12, 3.5]}, "octomap": name},
        "start": {"position": [1.5, 3.9, 1.2]},
        "goal": {"position": [14.5, 6.9, 1.2]},
    }
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError, match=rf"world.octomap: {advice}"):
        load_scenario(tmp_path / "s.yaml")


def _point_file_scenario(folder: Path, cloud: str, origin: list | None) -> Path:
    """cloud_server.yaml with ``server_map.cloud`` set to ``cloud`` (a file in ``folder``)."""
    data = yaml.safe_load((MAPS / "cloud_server.yaml").read_text())
    data["server_map"]["cloud"] = cloud
    if origin is None:
        del data["server_map"]["origin"]
    else:
        data["server_map"]["origin"] = origin
    path = folder / "s.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def test_octomap_point_file_server_map_is_rays_from_the_origin(
    octomap_dir: Path, tmp_path: Path, octomap_voxels
) -> None:
    """OctoMap's own scan.dat.bz2 (88,206 points of a real laser scan, bzip2-compressed) as the
    server map: voxel for voxel what octomap-python builds from the same points and origin; the
    plain .dat reads the same."""
    import bz2

    import octomap

    from secure3d.mapping.octomap_io import read_scan_dat

    (tmp_path / "scan.dat.bz2").write_bytes((octomap_dir / "scan.dat.bz2").read_bytes())
    s = load_scenario(_point_file_scenario(tmp_path, "scan.dat.bz2", [0.0, 0.0, 0.5]))
    pts = read_scan_dat(octomap_dir / "scan.dat.bz2")
    assert pts.shape == (88206, 3)
    occ, free = _claims(belief_map(s))
    tree = octomap.OcTree(0.1)
    tree.insertPointCloud(pts, np.array([0.0, 0.0, 0.5]))
    assert (len(occ), len(free)) == octomap_voxels(tree) and len(free) > 100_000
    centre = lambda keys: (np.array(sorted(keys)) + 0.5) * 0.1  # noqa: E731
    np.testing.assert_array_equal(tree.getLabels(centre(occ)), 1)
    np.testing.assert_array_equal(tree.getLabels(centre(free)), 0)
    # the same file uncompressed, and with no origin: only its points, nothing claimed free
    (tmp_path / "scan.dat").write_bytes(bz2.decompress((tmp_path / "scan.dat.bz2").read_bytes()))
    np.testing.assert_array_equal(read_cloud(tmp_path / "scan.dat"), pts)
    bare = load_scenario(_point_file_scenario(tmp_path, "scan.dat", None))
    occ_bare, free_bare = _claims(belief_map(bare))
    points_only = octomap.OcTree(0.1)  # OctoMap's keys of the points (float32 coordinates)
    for p in pts:
        points_only.updateNode(p, True)
    assert not free_bare and (len(occ_bare), 0) == octomap_voxels(points_only)
    np.testing.assert_array_equal(points_only.getLabels(centre(occ_bare)), 1)


@pytest.mark.parametrize(
    ("name", "content", "problem"),
    [
        ("bad.dat", b"1 2 3\n4 5 x\n", "non-numeric"),
        ("short.dat", b"1 2 3\n4 5\n", "not a multiple of 3"),
        ("empty.dat", b"", "holds no points"),
        ("nan.dat", b"nan 0 0\n", "no finite points"),
        ("cut.dat.bz2", None, "truncated"),
        ("plain.dat.bz2", b"1 2 3\n", "cannot read"),
    ],
)
def test_a_broken_point_file_is_a_one_line_scenario_error(
    octomap_dir: Path, tmp_path: Path, name: str, content: bytes | None, problem: str
) -> None:
    if content is None:  # a real compressed file cut short
        content = (octomap_dir / "scan.dat.bz2").read_bytes()[:5000]
    (tmp_path / name).write_bytes(content)
    with pytest.raises(ScenarioError) as err:
        load_scenario(_point_file_scenario(tmp_path, name, [0.0, 0.0, 0.0]))
    message = str(err.value)
    assert "server_map.cloud: " in message and name in message and problem in message
    assert "\n" not in message
