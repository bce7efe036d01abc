"""Scenario files: the library in maps/ loads, round-trips, and every kind of bad input is refused
with one line naming the file, the field and the value."""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml

from secure3d.errors import ScenarioError
from secure3d.world import (
    Bounds,
    Box,
    GoalSpec,
    Scenario,
    StartSpec,
    World,
    load_scenario,
    mesh_from_arrays,
    save_scenario,
    scenario_from_dict,
    scenario_to_dict,
)
from secure3d.world.scenario import MAX_SCENARIO_BYTES

REPO = Path(__file__).resolve().parents[2]
MAPS = REPO / "maps"
ALL_MAPS = sorted(MAPS.glob("*.yaml"))


@pytest.fixture(scope="module")
def scenarios() -> dict[str, Scenario]:
    return {p.stem: load_scenario(p) for p in ALL_MAPS}


@pytest.fixture
def sandbox(tmp_path: Path) -> Path:
    """A copy of maps/ (YAML, meshes, octomaps) that tests may corrupt."""
    for p in MAPS.rglob("*"):
        if p.is_file() and p.suffix in (".yaml", ".obj", ".ply", ".stl", ".bt", ".graph"):
            dest = tmp_path / p.relative_to(MAPS)
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(p.read_bytes())
    return tmp_path


def _raw(name: str) -> dict:
    return yaml.safe_load((MAPS / f"{name}.yaml").read_text())


def _write(folder: Path, data: dict, name: str = "bad.yaml") -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


# ------------------------------------------------------------------------------------------
# The library
# ------------------------------------------------------------------------------------------


def test_library_has_the_required_scenarios() -> None:
    names = {p.stem for p in ALL_MAPS}
    required = {
        "blind_corner",
        "narrow_passage_50cm",
        "narrow_passage_20cm",
        "forest",
        "warehouse",
        "planar_blind_corner",
        "planar_passage_50cm",
        "planar_passage_20cm",
        "paper_passage_50cm",
        "paper_passage_20cm",
        "paper_blind_corner",
    }
    assert required <= names, f"missing scenarios: {required - names}"


@pytest.mark.parametrize("path", ALL_MAPS, ids=lambda p: p.stem)
def test_every_scenario_loads_and_describes_itself(path: Path) -> None:
    s = load_scenario(path)
    assert s.name == path.stem, "scenario name should match its file name"
    assert len(s.description.split()) >= 30, "each scenario must state its purpose"
    assert "Purpose" in s.description
    assert s.source == path.resolve()
    text = str(s)
    assert text.splitlines()[0].startswith(f"Scenario '{s.name}'")
    assert all(len(line) <= 100 for line in text.splitlines()), "summary lines must fit 100 cols"
    for hidden in s.hidden_obstacles:
        assert any(hidden in line and "HIDDEN" in line for line in text.splitlines())


def test_library_uses_meshes_and_octomaps(scenarios: dict[str, Scenario]) -> None:
    assert any(s.world.meshes for s in scenarios.values()), "no scenario uses a mesh file"
    assert any(s.world.octomap or s.server_map.bt for s in scenarios.values()), "no .bt scenario"
    suffixes = {m.path.suffix for s in scenarios.values() for m in s.world.meshes}
    assert {".obj", ".ply"} <= suffixes


def test_asset_files_are_small() -> None:
    for p in (MAPS / "meshes").iterdir():
        assert p.stat().st_size < 200_000, f"{p.name} is larger than 200 KB"
    for p in (MAPS / "octomaps").iterdir():
        assert p.stat().st_size < 300_000, f"{p.name} is larger than 300 KB"


def test_paper_cases_have_the_stated_geometry(scenarios: dict[str, Scenario]) -> None:
    for name, gap, dims in (
        ("narrow_passage_50cm", 0.5, 3),
        ("narrow_passage_20cm", 0.2, 3),
        ("planar_passage_50cm", 0.5, 2),
        ("planar_passage_20cm", 0.2, 2),
        ("paper_passage_50cm", 0.5, 2),
        ("paper_passage_20cm", 0.2, 2),
    ):
        s = scenarios[name]
        np.testing.assert_allclose(s.start.velocity, (1.0, 0.0, 0.0), err_msg=name)
        left, right = s.world.obstacle("wall_left"), s.world.obstacle("wall_right")
        np.testing.assert_allclose(right.lo[1] - left.hi[1], gap, atol=1e-9, err_msg=name)
        assert 2 * s.vehicle.body_radius < gap, f"{name}: the body must fit through the gap"
        assert (s.vehicle.model == "diff_drive") == (dims == 2)
    for name in ("planar_blind_corner", "planar_passage_50cm", "paper_blind_corner"):
        c = scenarios[name].camera
        assert (c.hfov_deg, c.max_range, c.far_kind) == (120, 2.0, "range"), name
    corner = scenarios["blind_corner"]
    assert corner.hidden_obstacles == ("crate",)
    assert np.allclose(corner.start.velocity, 0.0)
    assert corner.camera.hfov_deg == 90 and corner.camera.max_range == 6.0


def test_mesh_placement_matches_the_file_geometry(scenarios: dict[str, Scenario]) -> None:
    # tree_trunk.obj is a 0.18 m radius, 4 m cylinder standing on z = 0 (maps/generate_assets.py).
    tree = scenarios["forest"].world.obstacle("tree_02")
    assert tree.scale == 1.1
    r, h = 0.18 * tree.scale, 4.0 * tree.scale
    np.testing.assert_allclose(tree.lo, np.add(tree.translate, (-r, -r, 0.0)), atol=1e-6)
    np.testing.assert_allclose(tree.hi, np.add(tree.translate, (r, r, h)), atol=1e-6)
    direct = trimesh.load(MAPS / "meshes" / "tree_trunk.obj", force="mesh")
    np.testing.assert_allclose(
        np.sort(tree.vertices, axis=0),
        np.sort(direct.vertices * tree.scale + tree.translate, axis=0),
        atol=1e-9,
        err_msg="loaded vertices must be scale * file + translate",
    )


# ------------------------------------------------------------------------------------------
# Round trips
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("path", ALL_MAPS, ids=lambda p: p.stem)
def test_round_trip_through_yaml(path: Path, sandbox: Path) -> None:
    original = load_scenario(sandbox / path.name)
    again = load_scenario(save_scenario(original, sandbox / "again.yaml"))
    assert scenario_to_dict(again) == scenario_to_dict(original)
    for a, b in zip(original.world.meshes, again.world.meshes, strict=True):
        np.testing.assert_array_equal(a.vertices, b.vertices)
    assert again.world.octomap == original.world.octomap
    assert again.server_map == original.server_map


def test_python_built_scenario_with_inline_mesh_round_trips(tmp_path: Path) -> None:
    cube = trimesh.creation.box((1.0, 1.0, 1.0))
    cube.apply_translation((5.0, 5.0, 0.5))
    s = Scenario(
        name="built",
        world=World(
            Bounds((0, 0, 0), (10, 10, 3)),
            boxes=(Box("wall", (4, 0, 0), (4.2, 3, 3)),),
            meshes=(mesh_from_arrays(cube.vertices, cube.faces, "cube"),),
        ),
        start=StartSpec((1, 1, 1)),
        goal=GoalSpec((9, 9, 1)),
    )
    data = scenario_to_dict(s)
    assert data["world"]["meshes"][0]["vertices"], "a mesh without a file is written inline"
    back = scenario_from_dict(yaml.safe_load(yaml.safe_dump(data)), tmp_path)
    assert scenario_to_dict(back) == data
    np.testing.assert_allclose(back.world.meshes[0].vertices, s.world.meshes[0].vertices)


def test_save_refuses_files_outside_the_destination(tmp_path: Path) -> None:
    s = load_scenario(MAPS / "warehouse.yaml")
    (tmp_path / "sub").mkdir()
    with pytest.raises(ScenarioError, match=r"world\.meshes\[0\]\.file"):
        save_scenario(s, tmp_path / "sub" / "w.yaml")


# ------------------------------------------------------------------------------------------
# Bad input: one line, file, field, value
# ------------------------------------------------------------------------------------------


def _set(path: str, value: object) -> Callable[[dict], None]:
    keys = path.split(".")

    def apply(d: dict) -> None:
        for k in keys[:-1]:
            d = d[int(k)] if isinstance(d, list) else d[k]
        d[int(keys[-1]) if isinstance(d, list) else keys[-1]] = value

    return apply


def _delete(path: str) -> Callable[[dict], None]:
    keys = path.split(".")

    def apply(d: dict) -> None:
        for k in keys[:-1]:
            d = d[k]
        del d[keys[-1]]

    return apply


def _rename(old: str, new: str) -> Callable[[dict], None]:
    def apply(d: dict) -> None:
        d[new] = d.pop(old)

    return apply


BAD_CORNER = [
    ("wrong type", _set("camera.hfov_deg", "wide"), "camera.hfov_deg", "expected a number"),
    ("float for int", _set("camera.width", 160.5), "camera.width", "integer"),
    ("string for bool", _set("camera.discretize", "yes"), "camera.discretize", "true or false"),
    ("bool for number", _set("goal.tolerance", True), "goal.tolerance", "number"),
    ("vector of text", _set("start.position", "1, 2, 3"), "start.position", "3 numbers"),
    ("missing field", _delete("start.position"), "start.position", "missing required"),
    ("missing section", _delete("world"), "world", "missing required"),
    ("missing bounds", _delete("world.bounds"), "world.bounds", "missing required"),
    ("typo top", _rename("vehicle", "vehical"), "vehical", "did you mean 'vehicle'"),
    ("typo nested", _set("camera.hfov", 90), "camera.hfov", "did you mean 'hfov_deg'"),
    ("inf in a box", _set("world.boxes.2.lo", [0, float("inf"), 0]), "world.boxes[2].lo", "finite"),
    ("empty box", _set("world.boxes.0.hi", [8.5, 9.0, -0.3]), "world.boxes[0].hi", "exceed lo"),
    (
        "box outside",
        _set("world.boxes.7", {"name": "far", "lo": [500, 0, 0], "hi": [501, 1, 1]}),
        "world.boxes[7]",
        "outside world.bounds",
    ),
    ("duplicate name", _set("world.boxes.7.name", "floor"), "world.boxes[7].name", "repeats"),
    ("absurd world", _set("world.bounds.hi", [1e5, 9.0, 2.8]), "world.bounds", "extent"),
    (
        "absurd voxel count",
        _set("world.bounds", {"lo": [-0.5, -0.5, -0.3], "hi": [1500, 1500, 30]}),
        "world.bounds",
        "voxels",
    ),
    ("absurd radius", _set("vehicle.body_radius", 50.0), "vehicle.body_radius", "<= 5"),
    ("absurd image", _set("camera.width", 100000), "camera.width", "[8, 4096]"),
    ("coarse map", _set("server_map.resolution", 10.0), "server_map.resolution", "[0.01, 2]"),
    ("start outside", _set("start.position", [20.0, 1.25, 1.25]), "start.position", "bounds"),
    ("start in wall", _set("start.position", [3.0, 2.4, 1.25]), "start.position", "inner_block"),
    ("goal in crate", _set("goal.position", [6.0, 3.8, 1.25]), "goal.position", "crate"),
    (
        "unknown target",
        _set("server_map.attacks.0.target", "ghost"),
        "server_map.attacks[0].target",
        "not an obstacle",
    ),
    (
        "bad attack kind",
        _set("server_map.attacks.0.kind", "delete"),
        "server_map.attacks[0].kind",
        "one of",
    ),
    (
        "shift without offset",
        _set("server_map.attacks.0.kind", "shift"),
        "server_map.attacks[0].offset",
        "missing",
    ),
    (
        "bt with attacks",
        _set("server_map.bt", "octomaps/office_server.bt"),
        "server_map.attacks",
        "only region attacks",
    ),
    ("negative limit", _set("vehicle.limits.max_accel", -4.0), "vehicle.limits.max_accel", "> 0"),
    ("unknown limit", _set("vehicle.limits.max_acel", 4.0), "vehicle.limits.max_acel", "unknown"),
    ("bad model", _set("vehicle.model", "helicopter"), "vehicle.model", "one of"),
    ("escape via ..", _set("world.octomap", "../outside.bt"), "world.octomap", "outside"),
    ("absolute path", _set("world.octomap", "/etc/hostname"), "world.octomap", "absolute"),
    ("missing file", _set("world.octomap", "octomaps/nope.bt"), "world.octomap", "no such file"),
    ("only unknown keys", lambda d: d.clear() or d.update({"x": 1}), "x", "unknown key"),
]


@pytest.mark.parametrize(
    ("mutate", "field", "problem"), [c[1:] for c in BAD_CORNER], ids=[c[0] for c in BAD_CORNER]
)
def test_bad_corner_file_names_file_field_and_problem(
    sandbox: Path, mutate: Callable[[dict], None], field: str, problem: str
) -> None:
    (sandbox.parent / "outside.bt").write_bytes(b"x")
    data = copy.deepcopy(_raw("blind_corner"))
    mutate(data)
    path = _write(sandbox, data)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert "\n" not in message, "errors must be one line"
    assert message.startswith(f"{path}: {field}"), message
    assert problem in message, message


BAD_DIFF_DRIVE = [
    ("sideways start", _set("start.velocity", [0.0, 1.0, 0.0]), "start.velocity", "heading"),
    ("climbing start", _set("start.velocity", [1.0, 0.0, 0.5]), "start.velocity", "heading"),
    ("wrong height", _set("goal.position", [4.5, 0.0, 0.8]), "goal.position", "fixed height"),
]


@pytest.mark.parametrize(
    ("mutate", "field", "problem"),
    [c[1:] for c in BAD_DIFF_DRIVE],
    ids=[c[0] for c in BAD_DIFF_DRIVE],
)
def test_bad_diff_drive_start(
    sandbox: Path, mutate: Callable[[dict], None], field: str, problem: str
) -> None:
    data = copy.deepcopy(_raw("planar_passage_50cm"))
    mutate(data)
    path = _write(sandbox, data)
    with pytest.raises(ScenarioError, match=rf"^{path}: {field}.*{problem}"):
        load_scenario(path)


BASE_TEXT = (MAPS / "blind_corner.yaml").read_text()
BAD_TEXT = [
    (
        "nan",
        BASE_TEXT.replace("position: [1.0, 1.25", "position: [1.0, .nan"),
        "start.position",
        "finite",
    ),
    (
        "duplicate key",
        BASE_TEXT + "start: {position: [2, 2, 2]}\n",
        "line",
        "duplicate key 'start'",
    ),
    ("syntax", "world: {bounds: [1, 2\n", "line", "YAML error"),
    ("empty", "", "(top level)", "empty"),
    ("list", "- 1\n- 2\n", "(top level)", "mapping"),
    (
        "exponent",
        BASE_TEXT.replace("time_limit: 20", "time_limit: 1e3"),
        "simulation.time_limit",
        "1.0e3",
    ),
    ("int key", "1: 2\n", "line 1", "keys must be strings"),
]


@pytest.mark.parametrize(
    ("text", "field", "problem"), [c[1:] for c in BAD_TEXT], ids=[c[0] for c in BAD_TEXT]
)
def test_bad_yaml_text(tmp_path: Path, text: str, field: str, problem: str) -> None:
    assert text != BASE_TEXT, "the replacement must change the file"
    path = tmp_path / "t.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"{path}: "), message
    assert field in message and problem in message, message


def test_file_size_and_kind_limits(tmp_path: Path) -> None:
    big = tmp_path / "big.yaml"
    big.write_text("name: x\n" + "#" * MAX_SCENARIO_BYTES)
    with pytest.raises(ScenarioError, match="at most 1000000 bytes"):
        load_scenario(big)
    with pytest.raises(ScenarioError, match="not a regular file"):
        load_scenario(tmp_path)
    with pytest.raises(ScenarioError, match="no such file"):
        load_scenario(tmp_path / "missing.yaml")
    binary = tmp_path / "bin.yaml"
    binary.write_bytes(b"name: \xff\xfe\n")
    with pytest.raises(ScenarioError, match="UTF-8"):
        load_scenario(binary)


def test_mesh_path_escapes_are_refused(sandbox: Path, tmp_path_factory) -> None:
    outside = tmp_path_factory.mktemp("outside") / "tree.obj"
    outside.write_bytes((MAPS / "meshes" / "tree_trunk.obj").read_bytes())
    cases = {
        "dotdot": f"../{outside.parent.name}/tree.obj",
        "absolute": str(outside),
        "symlink": "meshes/link.obj",
    }
    (sandbox / "meshes" / "link.obj").symlink_to(outside)
    for label, ref in cases.items():
        data = _raw("forest")
        data["world"]["meshes"][0]["file"] = ref
        path = _write(sandbox, data)
        with pytest.raises(ScenarioError) as info:
            load_scenario(path)
        message = str(info.value)
        assert message.startswith(f"{path}: world.meshes[0].file: "), (label, message)
        assert "outside" in message or "absolute" in message, (label, message)


@pytest.mark.parametrize(
    ("content", "problem"),
    [
        (b"\x00\x01garbage that is not a mesh", "no triangles"),
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n", "watertight"),
        (
            b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 4 3\n",
            "positive volume",
        ),
    ],
    ids=["garbage", "open surface", "inside out"],
)
def test_broken_mesh_files_are_refused(sandbox: Path, content: bytes, problem: str) -> None:
    (sandbox / "meshes" / "broken.obj").write_bytes(content)
    data = _raw("warehouse")
    data["world"]["meshes"][1]["file"] = "meshes/broken.obj"
    path = _write(sandbox, data)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert message.startswith(f"{path}: world.meshes[1].file: "), message
    assert "broken.obj" in message and problem in message, message


def test_mesh_scale_and_format_are_checked(sandbox: Path) -> None:
    data = _raw("warehouse")
    data["world"]["meshes"][0]["scale"] = -1.0
    with pytest.raises(ScenarioError, match=r"world\.meshes\[0\]\.scale: must be in"):
        load_scenario(_write(sandbox, data))
    (sandbox / "meshes" / "crate.txt").write_text("v 0 0 0\n")
    data = _raw("warehouse")
    data["world"]["meshes"][0]["file"] = "meshes/crate.txt"
    with pytest.raises(ScenarioError, match=r"world\.meshes\[0\]\.file: mesh files must be"):
        load_scenario(_write(sandbox, data))


def test_python_api_checks_the_same_invariants() -> None:
    world = World(Bounds((0, 0, 0), (10, 10, 3)), boxes=(Box("b", (4, 4, 0), (6, 6, 3)),))
    with pytest.raises(ScenarioError, match="start.position.*bounds"):
        Scenario("s", world, StartSpec((0.1, 5, 1)), GoalSpec((9, 9, 1)))
    with pytest.raises(ScenarioError, match="goal.position.*'b'"):
        Scenario("s", world, StartSpec((1, 1, 1)), GoalSpec((5, 5, 1)))
    with pytest.raises(ScenarioError, match="hi: must exceed lo"):
        Box("flat", (0, 0, 0), (1, 1, 0))
    with pytest.raises(ScenarioError, match="start.position: must be finite"):
        StartSpec((0, math.nan, 0))
    with pytest.raises(ValueError):  # ScenarioError is a ValueError for callers that don't know it
        GoalSpec((0, 0, 0), tolerance=-1)


def test_error_path_uses_the_name_the_user_typed(
    sandbox: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    data = _raw("blind_corner")
    data["camera"]["rate_hz"] = 0
    _write(sandbox, data)
    monkeypatch.chdir(sandbox)
    with pytest.raises(ScenarioError, match=r"^bad\.yaml: camera\.rate_hz: must be > 0 \(got 0"):
        load_scenario("bad.yaml")


@pytest.mark.parametrize("field", ["world.octomap", "server_map.bt"])
def test_corrupt_octomap_is_refused_at_load(sandbox: Path, field: str) -> None:
    name = "office_truth.bt" if field == "world.octomap" else "office_server.bt"
    target = sandbox / "octomaps" / name
    target.write_bytes(target.read_bytes()[:-100])  # truncated
    with pytest.raises(ScenarioError) as info:
        load_scenario(sandbox / "office_bt.yaml")
    message = str(info.value)
    assert message.startswith(f"{sandbox / 'office_bt.yaml'}: {field}: "), message
    assert name in message and "not a valid OctoMap" in message and "\n" not in message


def _paths(d: object, path: tuple = ()) -> list[tuple]:
    out = [path] if path else []
    items = d.items() if isinstance(d, dict) else enumerate(d) if isinstance(d, list) else ()
    for k, v in items:
        out += _paths(v, (*path, k))
    return out


@pytest.mark.parametrize("name", ["blind_corner", "warehouse", "office_bt"])
def test_random_corruptions_raise_only_one_line_scenario_errors(name: str) -> None:
    """Seeded fuzzing: replace or delete random fields; nothing but ScenarioError may escape."""
    pool = [None, "x", [], {}, -1, 0, 1e9, math.nan, True, [1, 2], {"a": 1}, 10**30, [1, "a", 3]]
    base = _raw(name)
    paths = _paths(base)
    rng = np.random.default_rng(0)
    errors = 0
    for _ in range(60):
        data = copy.deepcopy(base)
        *parents, last = paths[rng.integers(len(paths))]
        target = data
        for k in parents:
            target = target[k]
        if isinstance(target, dict) and rng.random() < 0.2:
            del target[last]
        else:
            target[last] = copy.deepcopy(pool[rng.integers(len(pool))])
        try:
            scenario_from_dict(data, MAPS, label="fuzz.yaml")
        except ScenarioError as exc:
            errors += 1
            assert str(exc).startswith("fuzz.yaml: ") and "\n" not in str(exc), str(exc)
    assert errors >= 40, "most random corruptions must be caught"


@pytest.mark.parametrize(
    ("starts", "problem"),
    [([0.5, 1.5], r"in \(0, 1\]"), (0.5, "expected a list"), (["fast"], "number")],
)
def test_extra_starts_in_a_scenario_are_checked(
    sandbox: Path, starts: object, problem: str
) -> None:
    data = copy.deepcopy(_raw("paper_passage_50cm"))
    data["planner"]["extra_starts"] = starts
    path = _write(sandbox, data)
    with pytest.raises(ScenarioError, match=rf"^{path}: planner\.extra_starts.*{problem}"):
        load_scenario(path)


def test_extra_starts_reach_the_planner() -> None:
    from secure3d.planning.problem import problem_from_scenario

    scenario = load_scenario(MAPS / "paper_passage_50cm.yaml")
    assert scenario.planner.extra_starts == (0.4, 0.6, 1.0)
    assert problem_from_scenario(scenario).options.extra_starts == (0.4, 0.6, 1.0)


@pytest.mark.parametrize("key", ["\n", " planner", "a\tb"])
def test_an_unknown_key_with_blanks_is_quoted_on_one_line(key: str) -> None:
    data = copy.deepcopy(_raw("blind_corner"))
    data[key] = None
    with pytest.raises(ScenarioError) as info:
        scenario_from_dict(data, MAPS, label="blind_corner.yaml")
    text = str(info.value)
    assert "\n" not in text and f"{key!r}: unknown key" in text


def test_what_a_server_map_file_lacks_is_checked(tmp_path: Path) -> None:
    """server_map.lacks names world obstacles a file or survey lacks (reported as hidden); a map
    derived from the world hides one with an attack instead."""
    text = (MAPS / "mesh_server.yaml").read_text()
    assert "lacks: [crate]" in text
    (tmp_path / "meshes").mkdir()
    name = "blind_corner_building.obj"
    (tmp_path / "meshes" / name).write_bytes((MAPS / "meshes" / name).read_bytes())
    cases = [
        (text, None),
        (text.replace("lacks: [crate]", "lacks: [barrel]"), "server_map.lacks[0]"),
        (text.replace("lacks: [crate]", "lacks: crate"), "server_map.lacks"),
        (
            text.replace("  mesh: meshes/blind_corner_building.obj\n", ""),
            "server_map.lacks",
        ),
    ]
    for i, (case, field) in enumerate(cases):
        path = tmp_path / f"s{i}.yaml"
        path.write_text(case)
        if field is None:
            assert load_scenario(path).hidden_obstacles == ("crate",)
            continue
        with pytest.raises(ScenarioError, match=rf"{re.escape(field)}") as info:
            load_scenario(path)
        assert "\n" not in str(info.value)
