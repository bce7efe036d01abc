"""The ``survey`` family: a server map that is a lidar survey made before the world changed.
Real Open3D ray casting, the real scan-graph reader, real failure files."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

import secure3d
from secure3d.errors import ScenarioError
from secure3d.mapping.scan_graph import read_scan_graph_bytes
from secure3d.world import load_scenario, save_scenario
from secure3d.world.attacks import belief_map, true_obstacles
from secure3d.world.families import family_variants
from secure3d.world.family_registry import FAMILIES

SURVEY = FAMILIES["survey"]


def _inside(points: np.ndarray, lo: np.ndarray, hi: np.ndarray, pad: float) -> np.ndarray:
    return np.all((points >= lo - pad) & (points <= hi + pad), axis=1)


def _on(points: np.ndarray, boxes: tuple, pad: float) -> np.ndarray:
    """Which points lie within ``pad`` of one of the boxes ``(lo (k, 3), hi (k, 3))``."""
    lo, hi = boxes
    hit = np.zeros(len(points), bool)
    for k in range(0, len(lo), 256):  # chunks of boxes: bounded memory
        a, b = lo[k : k + 256, None] - pad, hi[k : k + 256, None] + pad
        hit |= np.any(np.all((points >= a) & (points <= b), axis=2), axis=0)
    return hit


@pytest.mark.parametrize("base_name", ["blind_corner", "warehouse", "office_bt"])
def test_survey_variants_are_pure_posed_scans_of_the_world_before_it_changed(maps_dir, base_name):
    base = secure3d.load_scenario(maps_dir / f"{base_name}.yaml")
    variants = family_variants(SURVEY, base, 3, seed=5)
    again = family_variants(SURVEY, base, 3, seed=5)
    for v, w in zip(variants, again, strict=True):
        assert v.server_map.survey == w.server_map.survey and v.world == w.world  # pure
        assert v.server_map.survey is not None and not v.server_map.from_world
        assert not [a for a in v.server_map.attacks if a.region is None]
        graph = read_scan_graph_bytes(v.server_map.survey)
        assert 2 <= len(graph.origins) <= 4
        assert not np.allclose(graph.rotations, [1.0, 0.0, 0.0, 0.0])  # posed scans
        hidden = v.world.boxes[len(base.world.boxes) :]
        assert len(hidden) == 1
        # the survey predates it: the variant says so, and a flight reports its first sight
        assert hidden[0].name in v.server_map.lacks and hidden[0].name in v.hidden_obstacles
        moved = [n for n in base.world.obstacle_names if f" {n} stood " in v.description]
        assert set(moved) <= set(v.server_map.lacks)  # surveyed where it stood before
        lo, hi = np.array(hidden[0].lo), np.array(hidden[0].hi)
        # the survey predates it: returns inside it, and occupied claims there, lie on an
        # obstacle it touches (the scene's own), never on it alone
        boxes = true_obstacles(base).aabbs()
        inner = _inside(graph.points, lo, hi, -1e-3)
        assert _on(graph.points[inner], boxes, 1e-3).all()
        occ = belief_map(v).claimed_voxels(True)
        inner = _inside(occ, lo, hi, -0.051)
        assert _on(occ[inner], boxes, 0.051).all()
        # every return lies on a surveyed surface: within a voxel of some true obstacle, or of
        # the moved one where it stood
        assert _on(graph.points[::20], boxes, 1.05).mean() > 0.95
    assert variants[0].server_map.survey != variants[1].server_map.survey


def test_a_survey_variant_saves_its_scan_graph_and_loads_back_the_same_claim(maps_dir, tmp_path):
    base = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    v = family_variants(SURVEY, base, 1, seed=3)[0]
    assert "scan graph survey held in memory" in v.summary()
    path = save_scenario(v, tmp_path / "variant.yaml")
    assert (tmp_path / "variant.graph").read_bytes() == v.server_map.survey
    back = load_scenario(path)
    assert back.server_map.cloud.name == "variant.graph" and back.server_map.survey is None
    a, b = belief_map(v), belief_map(back)
    np.testing.assert_array_equal(a.claimed_voxels(True), b.claimed_voxels(True))
    np.testing.assert_array_equal(a.claimed_voxels(False), b.claimed_voxels(False))
    # the plain data notes the survey; read as YAML it says what to do instead
    data = secure3d.world.scenario_to_dict(v, tmp_path)
    assert "bytes, sha256" in data["server_map"]["survey"]
    (tmp_path / "note.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(ScenarioError, match="server_map.survey: .*save_scenario"):
        load_scenario(tmp_path / "note.yaml")


def test_a_survey_variants_failure_file_carries_its_scan_graph(maps_dir, tmp_path):
    from secure3d.simulation.campaign_records import RunRecord
    from secure3d.simulation.campaign_store import failure_defaults, save_failure

    base = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    v = family_variants(SURVEY, base, 1, seed=3)[0]
    record = RunRecord(variant=0, scenario=v.name, seed=3, planner="secure", outcome="collided")
    path = save_failure(tmp_path, v, record, {"plan_budget": 10.0}, 0.5)
    again = load_scenario(path)
    assert again.server_map.cloud.read_bytes() == v.server_map.survey
    assert failure_defaults(path)["planner"] == "secure"
    np.testing.assert_array_equal(
        belief_map(again).claimed_voxels(True), belief_map(v).claimed_voxels(True)
    )


def test_a_survey_campaign_flies_and_the_secure_robot_does_not_collide(maps_dir, tmp_path):
    from secure3d.simulation.campaign import run_campaign

    base = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    flown = {"planners": ("secure",), "seed": 5, "workers": 1, "progress": False, "nodes": 20}
    result = run_campaign(base, 2, out_dir=tmp_path, kind="survey", **flown)
    names = [v.name for v in family_variants(SURVEY, base, 2, seed=5)]
    assert [r.scenario for r in result.records] == names
    assert not any(r.collided for r in result.records)
    assert not any(r.error for r in result.records), [r.error for r in result.records]


def test_bad_survey_bytes_are_refused_by_name(maps_dir):
    import dataclasses

    base = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    with pytest.raises(ScenarioError, match="server_map.survey: must be a scan graph's bytes"):
        dataclasses.replace(base.server_map, attacks=(), survey="not bytes")
    broken = dataclasses.replace(
        base, server_map=dataclasses.replace(base.server_map, attacks=(), survey=b"\x05\0\0\0")
    )
    with pytest.raises(ScenarioError, match="server_map.survey: 5 nodes do not fit"):
        belief_map(broken)


def test_survey_scans_refuse_bad_input_by_name():
    from secure3d.errors import GeometryError
    from secure3d.world.survey_families import survey_scans

    v, f = np.eye(3), np.array([[0, 1, 2]])
    pose = [(np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]))]
    with pytest.raises(GeometryError, match="half_elevation_deg"):
        survey_scans(v, f, pose, 95.0)
    with pytest.raises(GeometryError, match="vertices and faces"):
        survey_scans(v[:, :2], f, pose, 20.0)
    with pytest.raises(GeometryError, match="unit quaternion"):
        survey_scans(v, f, [(np.zeros(3), np.array([0.0, 0.0, 0.0, 0.0]))], 20.0)
    # a lidar at the origin sees the triangle x + y + z = 1 (the rays towards it)
    ((pts, t, q),) = survey_scans(v, f, pose, 30.0)
    assert len(pts) and np.allclose(pts.sum(axis=1), 1.0, atol=1e-5)


def test_a_phantom_surveyed_elsewhere_leaves_nothing_out_of_the_world(maps_dir):
    """warehouse's server invents phantom_pallet; a survey variant that moves it (seed 3501,
    variant 1) named it in ``lacks``, which holds only the world's obstacles: every run of that
    variant was an error row."""
    from secure3d.world.families import variant_rng
    from secure3d.world.survey_families import SURVEY

    base = secure3d.load_scenario(maps_dir / "warehouse.yaml")
    v = SURVEY.variant(SURVEY.prepare(base), base, variant_rng(3501, 1), 1)
    assert "phantom_pallet stood" in v.description
    assert "phantom_pallet" not in v.server_map.lacks
    assert set(v.server_map.lacks) <= {b.name for b in v.world.boxes}
    occupied = belief_map(v).claimed_voxels(occupied=True)
    assert len(occupied)  # the survey's claims load


def _narrowest_gap(hidden: object, boxes: tuple) -> float:
    """Smallest distance (m) from box ``hidden`` to the ones it does not touch."""
    from secure3d.world.spec import box_distance

    lo, hi = np.array([b.lo for b in boxes]), np.array([b.hi for b in boxes])
    d = box_distance(hidden.lo, hidden.hi, lo, hi)
    return float(d[d > 0].min())


def test_a_survey_campaign_leaves_gaps_its_robot_can_pass_at_a_standstill(maps_dir):
    """A campaign's survey family places its hidden obstacle as the ``auto`` family does: the gaps
    beside it hold twice the secure planner's footprint at rest after losing a map voxel on each
    side. For the quadrotor (0.315 m a side) the body-radius rule alone left 0.74 m (seed 3601,
    variant 0): every replan beside it crawled or ran out of its budget."""
    from secure3d.planning.problem import rest_footprint
    from secure3d.simulation.campaign_run import campaign_family

    base = secure3d.load_scenario(maps_dir / "blind_corner_quadrotor.yaml")
    keep = 2 * rest_footprint(base) + 2 * base.server_map.resolution
    assert keep == pytest.approx(0.83, abs=0.01)
    family = campaign_family(base, "survey", 1, {})
    assert family.name == "survey"
    v = family_variants(family, base, 1, seed=3601)[0]
    assert _narrowest_gap(v.world.boxes[-1], base.world.boxes) >= keep - 1e-9
    old = family_variants(SURVEY, base, 1, seed=3601)[0]  # the registry's: the body radius only
    assert _narrowest_gap(old.world.boxes[-1], base.world.boxes) < keep
    # the point mass's footprint asks no more than its body rule: its variants are unchanged
    flat = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    same = family_variants(campaign_family(flat, "survey", 1, {}), flat, 1, seed=3601)[0]
    assert same.world == family_variants(SURVEY, flat, 1, seed=3601)[0].world


@pytest.mark.parametrize("bad", [-0.1, 0.0, 7.0, float("nan"), "0.3"])
def test_a_survey_family_refuses_a_bad_footprint_by_name(bad):
    from secure3d.world.survey_families import survey_family

    with pytest.raises(ScenarioError, match=r"footprint: must be a number of metres"):
        survey_family(bad)
