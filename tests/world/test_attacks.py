"""Server claims (hide, stale, phantom, shift, own .bt) and random hidden-obstacle variants."""

from __future__ import annotations

import dataclasses
from collections import deque
from pathlib import Path

import numpy as np
import pytest

from secure3d.errors import ScenarioError
from secure3d.mapping.occupancy import OccupancyMap
from secure3d.world import (
    Attack,
    Bounds,
    Box,
    GoalSpec,
    Scenario,
    ServerMapSpec,
    StartSpec,
    World,
    belief_map,
    load_scenario,
    random_hidden_obstacle_scenarios,
    scenario_from_dict,
    scenario_to_dict,
    server_claim,
    true_obstacles,
)

MAPS = Path(__file__).resolve().parents[2] / "maps"


@pytest.fixture(scope="module")
def corner() -> Scenario:
    return load_scenario(MAPS / "blind_corner.yaml")


@pytest.fixture(scope="module")
def forest() -> Scenario:
    return load_scenario(MAPS / "forest.yaml")


# ------------------------------------------------------------------------------------------
# server_claim
# ------------------------------------------------------------------------------------------


def test_hide_removes_exactly_the_target(corner: Scenario) -> None:
    claim = server_claim(corner)
    assert [b.name for b in claim.boxes] == [
        b.name for b in corner.world.boxes if b.name != "crate"
    ]
    for b in claim.boxes:
        assert b == corner.world.obstacle(b.name), f"{b.name} must be reported unchanged"
    assert claim.meshes == () and claim.bt is None


def test_phantom_and_shift(tmp_path: Path) -> None:
    s = load_scenario(MAPS / "warehouse.yaml")
    claim = server_claim(s)
    names = [b.name for b in claim.boxes]
    assert names == ["floor", "shelf_1", "shelf_2", "shelf_3", "phantom_pallet"]
    phantom = claim.boxes[-1]
    assert phantom.lo == (8.0, 2.8, 0.0) and phantom.hi == (9.0, 5.0, 3.5)
    true3, claimed3 = s.world.obstacle("shelf_3"), claim.boxes[3]
    np.testing.assert_allclose(np.subtract(claimed3.lo, true3.lo), (0, 0.6, 0), atol=1e-12)
    np.testing.assert_allclose(np.subtract(claimed3.hi, true3.hi), (0, 0.6, 0), atol=1e-12)
    assert [m.name for m in claim.meshes] == [m.name for m in s.world.meshes]
    for m in claim.meshes:
        np.testing.assert_array_equal(m.vertices, s.world.obstacle(m.name).vertices)
    assert "phantom_pallet" not in s.world.obstacle_names, "a phantom must not become real"


def test_hide_and_stale_on_meshes(forest: Scenario) -> None:
    claim = server_claim(forest)
    hidden = {"tree_10", "tree_13", "tree_16"}
    assert set(forest.hidden_obstacles) == hidden
    assert {m.name for m in claim.meshes} == {m.name for m in forest.world.meshes} - hidden
    assert len(claim.meshes) == 17


def test_server_map_given_as_bt() -> None:
    s = load_scenario(MAPS / "office_bt.yaml")
    claim = server_claim(s)
    assert claim.boxes == () and claim.meshes == ()
    assert claim.bt == (MAPS / "octomaps" / "office_server.bt").resolve()
    assert s.world.octomap == (MAPS / "octomaps" / "office_truth.bt").resolve()


def test_true_octomap_is_reported_as_is() -> None:
    s = load_scenario(MAPS / "office_bt.yaml")
    honest = dataclasses.replace(s, server_map=ServerMapSpec(resolution=0.1))
    assert server_claim(honest).bt == s.world.octomap


def _built(attacks: tuple[Attack, ...]) -> Scenario:
    return Scenario(
        name="built",
        world=World(
            Bounds((0, 0, 0), (10, 10, 3)),
            boxes=(
                Box("a", (2, 2, 0), (3, 3, 3)),
                Box("b", (5, 5, 0), (6, 6, 3)),
                Box("c", (7, 1, 0), (8, 2, 3)),
                Box("d", (1, 7, 0), (2, 8, 3)),
            ),
        ),
        start=StartSpec((0.5, 0.5, 1)),
        goal=GoalSpec((9.5, 9.5, 1)),
        server_map=ServerMapSpec(attacks=attacks),
    )


def test_all_attack_kinds_together_in_python() -> None:
    s = _built(
        (
            Attack("shift", target="a", offset=(0.5, 0, 0)),
            Attack("hide", target="b"),
            Attack("phantom", box=Box("ghost", (4, 8, 0), (5, 9, 3))),
            Attack("stale", target="d"),
        )
    )
    claim = server_claim(s)
    assert [b.name for b in claim.boxes] == ["a", "c", "ghost"]
    assert claim.boxes[0].lo == (2.5, 2.0, 0.0) and claim.boxes[0].hi == (3.5, 3.0, 3.0)
    assert s.hidden_obstacles == ("b", "d")


def test_inconsistent_attacks_are_refused() -> None:
    with pytest.raises(ScenarioError, match=r"attacks\[1\]\.target: each obstacle"):
        _built((Attack("hide", target="a"), Attack("shift", target="a", offset=(1, 0, 0))))
    with pytest.raises(ScenarioError, match=r"attacks\[0\]\.box\.name: a phantom needs"):
        _built((Attack("phantom", box=Box("c", (4, 8, 0), (5, 9, 3))),))
    with pytest.raises(ScenarioError, match=r"attacks\[0\]\.target: not an obstacle"):
        _built((Attack("hide", target="zzz"),))
    with pytest.raises(ScenarioError, match="offset"):
        Attack("shift", target="a")
    with pytest.raises(ScenarioError, match="attack.kind"):
        Attack("erase", target="a")


# ------------------------------------------------------------------------------------------
# random_hidden_obstacle_scenarios
# ------------------------------------------------------------------------------------------


def _point_box_distance(p: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    return float(np.linalg.norm(p - np.clip(p, lo, hi)))


def _box_gap(lo_a, hi_a, lo_b, hi_b) -> float:
    per_axis = [max(0.0, lo_b[k] - hi_a[k], lo_a[k] - hi_b[k]) for k in range(3)]
    return float(np.sqrt(sum(g * g for g in per_axis)))


def _reachable_2d(s: Scenario, step: float = 0.05) -> bool:
    """Breadth-first search on the horizontal slice at the start's height, disc-inflated by r.

    Independent of the generator's own check (3D, cube inflation, connected components)."""
    r, z = s.vehicle.body_radius, s.start.position[2]
    b = s.world.bounds
    lo, hi = true_obstacles(s).aabbs()
    near = (hi[:, 2] > z - r) & (lo[:, 2] < z + r)
    xs = np.arange(b.lo[0] + r, b.hi[0] - r + 1e-9, step)
    ys = np.arange(b.lo[1] + r, b.hi[1] - r + 1e-9, step)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    free = np.ones(gx.shape, dtype=bool)
    for olo, ohi in zip(lo[near], hi[near], strict=True):
        # only the cells within r of the box can be blocked by it
        i = slice(*np.searchsorted(xs, [olo[0] - r, ohi[0] + r]))
        j = slice(*np.searchsorted(ys, [olo[1] - r, ohi[1] + r]))
        dx = np.maximum(0, np.maximum(olo[0] - gx[i, j], gx[i, j] - ohi[0]))
        dy = np.maximum(0, np.maximum(olo[1] - gy[i, j], gy[i, j] - ohi[1]))
        free[i, j] &= np.hypot(dx, dy) >= r
    start = tuple(np.argmin(abs(g - p)) for g, p in zip((xs, ys), s.start.position, strict=False))
    goal = tuple(np.argmin(abs(g - p)) for g, p in zip((xs, ys), s.goal.position, strict=False))
    seen = np.zeros_like(free)
    queue = deque([start])
    seen[start] = True
    while queue:
        i, j = queue.popleft()
        if (i, j) == goal:
            return True
        for di, dj in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            a, c = i + di, j + dj
            if 0 <= a < free.shape[0] and 0 <= c < free.shape[1] and free[a, c] and not seen[a, c]:
                seen[a, c] = True
                queue.append((a, c))
    return False


def _check_variant(base: Scenario, v: Scenario, count: int = 1) -> list[Box]:
    r = base.vehicle.body_radius
    keep = r + 0.3
    new = list(v.world.boxes[len(base.world.boxes) :])
    assert v.world.boxes[: len(base.world.boxes)] == base.world.boxes
    assert len(new) == count
    assert v.server_map.attacks[: len(base.server_map.attacks)] == base.server_map.attacks
    if base.server_map.bt is None:
        assert set(v.hidden_obstacles) - set(base.hidden_obstacles) == {b.name for b in new}
    else:  # the server's own .bt already lacks it: the variant says so, for its detection
        assert v.server_map.lacks == (*base.server_map.lacks, *(b.name for b in new))
        assert dataclasses.replace(v.server_map, lacks=base.server_map.lacks) == base.server_map
        assert set(v.hidden_obstacles) - set(base.hidden_obstacles) == {b.name for b in new}
    claim_names = {o.name for o in (*server_claim(v).boxes, *server_claim(v).meshes)}
    truth = true_obstacles(base)
    base_lo, base_hi = truth.aabbs()
    named = len(base_lo) - len(truth.voxel_boxes)  # voxels come last
    for box in new:
        assert box.name not in claim_names, "the server must not report the new obstacle"
        lo, hi = np.array(box.lo), np.array(box.hi)
        for p in (base.start.position, base.goal.position):
            assert _point_box_distance(np.array(p), lo, hi) >= keep - 1e-9
        bottoms = np.append(base_hi[:, 2], base.world.bounds.lo[2])
        tops = np.append(base_lo[:, 2], base.world.bounds.hi[2])
        assert np.min(abs(box.lo[2] - bottoms)) < 1e-9, "must stand on something"
        assert np.min(abs(box.hi[2] - tops)) < 1e-9, "must reach up to something"
        # gaps to named obstacles and other new ones; a scanned wall's voxels are judged by the
        # route below instead
        others = [(base_lo[k], base_hi[k]) for k in range(named)]
        others += [(np.array(b.lo), np.array(b.hi)) for b in new if b is not box]
        for olo, ohi in others:
            if ohi[2] <= box.lo[2] + 1e-9 or olo[2] >= box.hi[2] - 1e-9:
                continue  # what it stands on or reaches up to
            gap = _box_gap(lo, hi, olo, ohi)
            assert gap == 0.0 or gap >= keep - 1e-9, f"{box.name} leaves a {gap:.3f} m sliver"
    assert _reachable_2d(v), f"{v.name}: the goal must stay reachable"
    if len(truth.voxel_boxes):
        # in a scanned world the route keeps a gap as wide as keep beside the new box
        grow = keep - 2 * r
        fat = [Box(b.name, tuple(np.subtract(b.lo, grow)), tuple(np.add(b.hi, grow))) for b in new]
        world = dataclasses.replace(v.world, boxes=(*base.world.boxes, *fat))
        assert _reachable_2d(dataclasses.replace(v, world=world)), f"{v.name}: a sliver route"
    return new


def test_variants_are_deterministic(corner: Scenario) -> None:
    a = random_hidden_obstacle_scenarios(corner, 3, 42)
    b = random_hidden_obstacle_scenarios(corner, 3, np.random.default_rng(42))
    c = random_hidden_obstacle_scenarios(corner, 3, 43)
    assert [scenario_to_dict(s) for s in a] == [scenario_to_dict(s) for s in b]
    assert [s.world.boxes[-1] for s in a] != [s.world.boxes[-1] for s in c]
    assert len({s.world.boxes[-1] for s in a}) == 3, "variants must differ from each other"
    assert [s.name for s in a] == [f"blind_corner_hidden_{i:03d}" for i in range(3)]


def test_corner_variants_hide_behind_the_corner(corner: Scenario) -> None:
    variants = random_hidden_obstacle_scenarios(corner, 8, 0, kind="auto")
    inner = corner.world.obstacle("inner_block")
    start = np.array(corner.start.position)
    for v in variants:
        assert "corner" in v.description
        (box,) = _check_variant(corner, v)
        # At least part of the footprint is out of the start's sight, behind the inner block.
        corners_xy = [(x, y) for x in (box.lo[0], box.hi[0]) for y in (box.lo[1], box.hi[1])]
        hidden = 0
        for x, y in corners_xy:
            t = np.linspace(0, 1, 400)[:, None]
            seg = start + t * (np.array([x, y, start[2]]) - start)
            inside = np.all((seg >= inner.lo) & (seg <= inner.hi), axis=1)
            hidden += bool(inside.any())
        assert hidden >= 1, f"{box} is fully visible from the start"
        assert box.lo[1] >= 2.0, "a blind-corner obstacle belongs around the corner, in leg 2"


def test_forest_variants_sit_between_start_and_goal(forest: Scenario) -> None:
    variants = random_hidden_obstacle_scenarios(forest, 4, 1, kind="forest", count=2)
    start, goal = np.array(forest.start.position), np.array(forest.goal.position)
    chord = goal - start
    for v in variants:
        for box in _check_variant(forest, v, count=2):
            centre = 0.5 * (np.array(box.lo) + np.array(box.hi))
            t = (centre - start) @ chord / (chord @ chord)
            assert 0.1 < t < 0.95, "a forest obstacle belongs along the way"
            assert max(np.subtract(box.hi, box.lo)[:2]) <= 0.5 + 1e-9, "trunk-sized footprint"


def test_variants_are_valid_scenarios(corner: Scenario, tmp_path: Path) -> None:
    (v,) = random_hidden_obstacle_scenarios(corner, 1, 5)
    back = scenario_from_dict(scenario_to_dict(v), tmp_path)
    assert scenario_to_dict(back) == scenario_to_dict(v)
    assert "hidden_0" in str(v) and "HIDDEN" in str(v)


def test_planar_corner_variants() -> None:
    planar = load_scenario(MAPS / "planar_blind_corner.yaml")
    for v in random_hidden_obstacle_scenarios(planar, 3, 2):
        _check_variant(planar, v)


def test_generator_input_errors(corner: Scenario) -> None:
    assert random_hidden_obstacle_scenarios(corner, 0, 0) == []
    with pytest.raises(ScenarioError, match="kind"):
        random_hidden_obstacle_scenarios(corner, 1, 0, kind="maze")
    with pytest.raises(ScenarioError, match="could not place"):
        random_hidden_obstacle_scenarios(corner, 1, 0, max_attempts=0)
    walled = dataclasses.replace(
        corner,
        world=dataclasses.replace(
            corner.world,
            boxes=(*corner.world.boxes, Box("seal", (5.5, 5.0, -0.3), (8.0, 5.5, 2.8))),
        ),
    )
    with pytest.raises(ScenarioError, match="no collision-free path"):
        random_hidden_obstacle_scenarios(walled, 1, 0)


def test_octomap_voxels_match_octomap_python() -> None:
    import octomap  # dev dependency: the reference implementation (DESIGN.md section 5)

    path = MAPS / "octomaps" / "office_truth.bt"
    boxes = true_obstacles(load_scenario(MAPS / "office_bt.yaml")).voxel_boxes
    tree = octomap.OcTree(str(path).encode())
    ref = []
    for leaf in tree.begin_leafs():
        if tree.isNodeOccupied(leaf):
            c, size = np.asarray(leaf.getCoordinate()), leaf.getSize()
            ref.append(np.concatenate([c - size / 2, c + size / 2]))
    ref = np.array(ref)
    ours = boxes.reshape(-1, 6)
    assert len(ours) == len(ref)
    order = np.lexsort(ours.T[::-1])
    ref_order = np.lexsort(np.round(ref, 6).T[::-1])
    np.testing.assert_allclose(ours[order], ref[ref_order], atol=1e-6, err_msg="occupied leaves")


def test_voxel_world_variants(tmp_path: Path) -> None:
    office = load_scenario(MAPS / "office_bt.yaml")
    for v in random_hidden_obstacle_scenarios(office, 2, 3):
        (box,) = _check_variant(office, v)
        assert box.lo[2] >= 0.1 - 1e-9, "stands on the floor voxels, not in them"


# ------------------------------------------------------------------------------------------
# belief_map
# ------------------------------------------------------------------------------------------


def test_belief_holds_the_claim_not_the_truth(corner: Scenario) -> None:
    belief = belief_map(corner)
    assert belief.resolution == corner.server_map.resolution
    np.testing.assert_allclose(belief.bounds[0], corner.world.bounds.lo)
    np.testing.assert_allclose(belief.bounds[1], corner.world.bounds.hi)
    rng = np.random.default_rng(0)
    b = corner.world.bounds
    pts = rng.uniform(b.lo, b.hi, size=(4000, 3))
    claim = server_claim(corner).boxes
    lo = np.array([c.lo for c in claim])
    hi = np.array([c.hi for c in claim])
    # Independent geometry: distance of each point to the nearest claimed box, and depth inside.
    outside = np.linalg.norm(pts[:, None] - np.clip(pts[:, None], lo, hi), axis=2).min(axis=1)
    depth = np.min(np.minimum(pts[:, None] - lo, hi - pts[:, None]), axis=2).max(axis=1)
    known = belief.is_known_obstacle(pts)
    res = belief.resolution
    assert known[depth > res].all(), "points deep inside a claimed box must be known obstacles"
    far = outside > res * np.sqrt(3)
    assert not known[far].any(), "points a voxel diagonal away from every claim must be free"
    assert far.sum() > 500 and (depth > res).sum() > 500, "the sample must exercise both cases"
    crate = corner.world.obstacle("crate")
    assert not belief.is_known_obstacle([np.add(crate.lo, crate.hi) / 2])[0], "crate is hidden"
    assert len(belief.occupied_voxels()) == 0, "no sensor evidence yet"


def test_belief_of_phantom_and_shift() -> None:
    s = load_scenario(MAPS / "warehouse.yaml")
    belief = belief_map(s)
    probes = np.array(
        [
            [8.5, 3.9, 1.2],  # inside the phantom pallet
            [8.0, 9.2, 1.2],  # where the server says shelf_3 is (shifted +0.6 m in y)
            [8.0, 8.2, 1.2],  # where shelf_3 really is but the server says is free
            [5.0, 6.3, 1.0],  # inside crate_1 (a mesh, reported honestly)
            [8.0, 7.0, 1.2],  # aisle C, truly free
        ]
    )
    np.testing.assert_array_equal(belief.is_known_obstacle(probes), [1, 1, 0, 1, 0])


def test_belief_from_server_bt_at_any_resolution() -> None:
    s = load_scenario(MAPS / "office_bt.yaml")
    probes = np.array(
        [
            [5.0, 1.0, 1.2],  # the partition wall
            [5.9, 5.0, 1.0],  # the cabinet the server's map lacks
            [5.0, 4.0, 1.2],  # the door
            [8.5, 6.5, 1.2],  # the goal
        ]
    )
    for res in (0.1, 0.2):
        belief = belief_map(s, resolution=res)
        assert belief.resolution == res
        np.testing.assert_array_equal(belief.is_known_obstacle(probes), [1, 0, 0, 0], err_msg=res)
    exact = belief_map(s)
    assert len(exact.claimed_voxels(occupied=False)) > 0, "a .bt also claims free space"


def _claim_arrays(belief):  # type: ignore[no-untyped-def]
    return belief.claimed_voxels(True), belief.claimed_voxels(False)


def test_cached_belief_is_a_fresh_independent_copy(tmp_path: Path) -> None:
    """A second belief of the same claim comes from the cache: equal to a fresh build, its own
    copy (changing it leaves the next one alone), and rebuilt when the file's content changes."""
    import shutil

    from secure3d.world import attacks

    bt = tmp_path / "server.bt"
    shutil.copy(MAPS / "octomaps" / "office_server.bt", bt)
    s = load_scenario(MAPS / "office_bt.yaml")
    s = dataclasses.replace(s, server_map=dataclasses.replace(s.server_map, bt=bt))
    first = belief_map(s)
    built = attacks._claimed_belief(server_claim(s), 0.1, (s.world.bounds.lo, s.world.bounds.hi))
    second = belief_map(s)
    assert second is not first
    for a, b in zip(_claim_arrays(second), _claim_arrays(built), strict=True):
        np.testing.assert_array_equal(a, b)
    boxes = second.known_obstacle_boxes()
    wall = np.array([[5.05, 1.05, 1.25]])  # a voxel centre in the partition wall
    assert first.is_known_obstacle(wall)[0]
    first.set_claim_voxels(wall, False)  # the caller's copy changes; the cache's does not
    assert not first.is_known_obstacle(wall)[0]
    third = belief_map(s)
    assert third.is_known_obstacle(wall)[0]
    for a, b in zip(third.known_obstacle_boxes(), boxes, strict=True):
        np.testing.assert_array_equal(a, b)  # merged once, shared by unchanged copies
    mine = first.known_obstacle_boxes()
    assert not any(
        np.all((m_lo < wall[0]) & (wall[0] < m_hi)) for m_lo, m_hi in zip(*mine, strict=True)
    ), "the changed copy merges its own boxes, without the voxel it freed"
    # Same size, other content: the digest, not a timestamp, notices.
    other = MAPS / "octomaps" / "office_truth.bt"
    data = other.read_bytes()
    bt.write_bytes(data)
    rebuilt = belief_map(s)
    truth = OccupancyMap.read_bt(other)
    probe = np.array([[5.9, 5.0, 1.0]])  # the cabinet only the truth's file holds
    assert truth.classify(probe)[0] == 1 and rebuilt.is_known_obstacle(probe)[0]
    bt.unlink()
    with pytest.raises(OSError):
        belief_map(s)  # a missing file is read (and refused) afresh, never served from the cache


def test_belief_cache_keeps_to_its_claim_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    """A belief claiming more voxels than the cache's budget is built afresh each time; smaller
    ones push out the least recently used until the cached claims fit."""
    from secure3d._bounded_cache import BoundedCache
    from secure3d.world import attacks

    def fresh() -> BoundedCache:
        return BoundedCache(attacks.BELIEF_CACHE_SIZE, attacks.MAX_CACHED_CLAIMS, attacks._claims)

    monkeypatch.setattr(attacks, "_BELIEFS", fresh())
    s = load_scenario(MAPS / "office_bt.yaml")
    claims = belief_map(s).claimed_count
    assert len(attacks._BELIEFS) == 1 and claims > 0
    monkeypatch.setattr(attacks._BELIEFS, "budget", claims - 1)
    coarse = belief_map(s, resolution=0.2)  # fewer claims: kept, and the first goes
    assert 0 < coarse.claimed_count < claims
    assert [k[2] for k in attacks._BELIEFS.keys()] == [0.2]
    monkeypatch.setattr(attacks, "_BELIEFS", fresh())
    monkeypatch.setattr(attacks._BELIEFS, "budget", claims - 1)
    belief_map(s)
    assert not len(attacks._BELIEFS), "a belief over the budget is not kept"


def test_auto_variants_fit_a_scanned_corridor() -> None:
    """A scanned corridor's walls are rough (geb079, 8 cm voxels): no box keeps the full gap from
    every voxel, so gaps to voxels are judged by the route, which must keep that gap beside the new
    box; and no box is squeezed between scanned clutter to less than planner.min_obstacle_size."""
    crate = load_scenario(MAPS / "geb079_hidden_crate.yaml")
    for v in random_hidden_obstacle_scenarios(crate, 3, 2701):
        (box,) = _check_variant(crate, v)
        assert np.min(np.subtract(box.hi, box.lo)) >= crate.planner.min_obstacle_size
