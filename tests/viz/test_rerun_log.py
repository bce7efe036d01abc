"""Rerun recorder: read the file back with Rerun's own reader and check what was logged."""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from secure3d.errors import ConfigError, SimulationError
from secure3d.viz.rerun_log import (
    TRUST_CLASSES,
    RerunRecorder,
    default_blueprint,
    ellipsoid_axes,
    recording_id,
)
from secure3d.world.spec import Bounds, Box

R_LOOK_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class StandInPlan:
    """The fields of ``PlanResult`` the recorder reads: a straight line at constant acceleration."""

    planner: str
    times: np.ndarray
    positions: np.ndarray
    ellipsoid_centers: np.ndarray
    ellipsoid_shapes: np.ndarray


def straight_plan(rng, planner="secure", K=8) -> StandInPlan:
    times = np.linspace(0.0, 2.0, K)
    positions = np.column_stack([0.5 * 1.5 * times**2, np.zeros(K), np.ones(K)])
    A = rng.normal(size=(K, 3, 3))
    shapes = A @ np.swapaxes(A, 1, 2) + 0.1 * np.eye(3)
    return StandInPlan(planner, times, positions, positions + [0.3, 0, 0], shapes)


def read_rows(path: Path) -> dict[str, list[dict]]:
    """Entity path -> rows (column name -> value), without Rerun's row ids."""
    from rerun.chunk import RrdReader

    rows: dict[str, list[dict]] = defaultdict(list)
    for chunk in RrdReader(path).stream().to_chunks():
        data = chunk.to_record_batch().to_pydict()
        data.pop("rerun.controls.RowId", None)
        n = chunk.num_rows
        rows[chunk.entity_path] += [{k: v[i] for k, v in data.items()} for i in range(n)]
    return dict(rows)


def write_demo(path: Path, rng, steps=12) -> dict:
    """Log a small run; returns what was logged for the checks."""
    plan = straight_plan(rng)
    depth = np.full((12, 16), np.inf, dtype=np.float32)
    depth[3:6, 4:9] = 2.5
    depth[0, 0] = np.nan
    centres = rng.uniform(0, 3, (30, 3))
    trust = np.arange(30, dtype=np.uint8) % 5
    times = 0.05 * np.arange(steps)
    with RerunRecorder(path, recording_id=recording_id("demo", 0), trail_period=0.1) as rec:
        rec.log_world(
            true_boxes=[Box("wall", (1, 1, 0), (2, 2, 2)), Box("ghost", (3, -1, 0), (4, 0, 2))],
            claimed_boxes=[Box("wall", (1, 1, 0), (2, 2, 2)), Box("fake", (5, 5, 0), (6, 6, 1))],
            hidden_names=["ghost"],
            bounds=Bounds((0, -2, 0), (8, 3, 3)),
        )
        for i, t in enumerate(times):
            rec.log_state(t, [t, 0, 1], [1, 0, 0], speed=1.0 + t, clearance=0.5 - t)
            rec.log_camera(t, R_LOOK_X, [t, 0, 1], 8.0, 8.0, 16, 12, depth)
            if i % 4 == 0:
                rec.log_plan(t, plan)
                rec.log_belief(t, centres, trust, 0.1)
                rec.log_scalar(t, "solve_time", 0.01 * (i + 1))
            if i == 5:
                rec.log_event(t, "hidden obstacle 'ghost' seen", level="warn")
    return {"plan": plan, "depth": depth, "trust": trust, "times": times}


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    path = tmp_path_factory.mktemp("rrd") / "demo.rrd"
    logged = write_demo(path, np.random.default_rng(0))
    return path, logged, read_rows(path)


def test_entities_counts_and_timeline(demo):
    path, logged, rows = demo
    n = len(logged["times"])
    expected = {
        "/world/robot": n,
        "/world/robot/velocity": n,
        "/world/camera": n,
        "/world/camera/image": n,
        "/world/camera/image/depth": n,
        "/world/plans/secure/path": 3,
        "/world/plans/secure/reactive": 3,
        "/events": 1,
        "/world/truth/obstacles": 1,
        "/world/truth/hidden": 1,
        "/world/server/claimed": 1,
        "/world/bounds": 1,
        "/legend": 1,
    }
    for entity, count in expected.items():
        assert len(rows.get(entity, [])) == count, entity
    # Time series: one static SeriesLines row plus one row per sample.
    speed = [r for r in rows["/metrics/speed"] if "sim_time" in r]
    assert len(speed) == n
    got_t = sorted(r["sim_time"].total_seconds() for r in speed)
    np.testing.assert_allclose(got_t, logged["times"], atol=1e-9)
    got_speed = [r["Scalars:scalars"][0] for r in sorted(speed, key=lambda r: r["sim_time"])]
    np.testing.assert_allclose(got_speed, 1.0 + logged["times"], atol=1e-12)
    # The trail is re-logged every trail_period of sim time, not at every step.
    trail_t = sorted(r["sim_time"].total_seconds() for r in rows["/world/robot/trail"])
    assert len(trail_t) < n and np.all(np.diff(trail_t) >= 0.1 - 1e-9)
    assert "/world/belief" in rows and "/metrics/solve_time" in rows


def test_world_hidden_and_phantom_obstacles(demo):
    _, _, rows = demo
    hidden = rows["/world/truth/hidden"][0]
    assert hidden["Boxes3D:labels"] == ["ghost"]
    claimed = rows["/world/server/claimed"][0]
    assert claimed["Boxes3D:labels"] == ["wall", "fake (phantom)"]
    assert rows["/world/truth/obstacles"][0]["Boxes3D:labels"] == ["wall"]


def test_reactive_ellipsoids_round_trip_to_the_shape_matrices(demo):
    _, logged, rows = demo
    plan = logged["plan"]
    row = rows["/world/plans/secure/reactive"][0]
    half = np.array(row["Ellipsoids3D:half_sizes"])
    quat = np.array(row["Ellipsoids3D:quaternions"])
    R = Rotation.from_quat(quat).as_matrix()
    M = R @ (half[:, :, None] * np.swapaxes(R, 1, 2))
    np.testing.assert_allclose(M, plan.ellipsoid_shapes, atol=1e-5, err_msg="M from the file")
    np.testing.assert_allclose(row["Ellipsoids3D:centers"], plan.ellipsoid_centers, atol=1e-6)
    path = np.array(rows["/world/plans/secure/path"][0]["LineStrips3D:strips"][0])
    np.testing.assert_allclose(path, plan.positions, atol=1e-6)


def test_depth_image_and_belief_classes(demo):
    _, logged, rows = demo
    row = rows["/world/camera/image/depth"][0]
    fmt = row["DepthImage:format"][0]
    assert fmt["width"] == 16 and fmt["height"] == 12
    img = np.array(row["DepthImage:buffer"][0], dtype=np.uint8).view(np.float32).reshape(12, 16)
    want = np.where(np.isfinite(logged["depth"]), logged["depth"], 0.0)
    np.testing.assert_array_equal(img, want)
    belief = rows["/world/belief"]
    context = [r for r in belief if "AnnotationContext:context" in r]
    assert len(context) == 1
    classes = [c["class_description"]["info"] for c in context[0]["AnnotationContext:context"][0]]
    labels = {c["id"]: c["label"] for c in classes}
    assert labels == {k: v[0] for k, v in TRUST_CLASSES.items()}
    boxes = [r for r in belief if "Boxes3D:class_ids" in r][0]
    trust = logged["trust"]
    assert boxes["Boxes3D:class_ids"] == trust[trust != 0].tolist()


def test_blueprint_is_in_the_file(demo):
    from rerun.chunk import RrdReader

    path, _, _ = demo
    reader = RrdReader(path)
    assert len(reader.blueprints()) == 1
    assert reader.recordings()[0].recording_id == recording_id("demo", 0)
    assert default_blueprint() is not None


def test_same_data_gives_the_same_recording(tmp_path):
    (tmp_path / "1").mkdir()
    (tmp_path / "2").mkdir()
    a, b = tmp_path / "1" / "run.rrd", tmp_path / "2" / "run.rrd"
    write_demo(a, np.random.default_rng(3))
    write_demo(b, np.random.default_rng(3))

    def canonical(path):
        return {e: sorted(map(repr, r)) for e, r in read_rows(path).items()}

    assert canonical(a) == canonical(b)


def test_output_is_atomic_and_interrupted_runs_leave_nothing(tmp_path):
    path = tmp_path / "run.rrd"
    rec = RerunRecorder(path)
    rec.log_event(0.0, "started")
    assert rec.part_path.exists() and not path.exists()
    rec.close()
    assert path.exists() and not rec.part_path.exists()
    assert rec.close() == path  # idempotent

    before = path.read_bytes()
    for exc in (RuntimeError("solver exploded"), KeyboardInterrupt()):
        with pytest.raises(type(exc)), RerunRecorder(path) as rec2:
            rec2.log_event(0.0, "started")
            raise exc
        assert not rec2.part_path.exists()
        assert path.read_bytes() == before, "an aborted run must not touch the previous file"


def test_belief_draws_only_voxels_that_can_show(tmp_path):
    """A solid 6^3 block of voxels is logged as its 152 outer boxes, sharing one half size; an
    outer voxel that is unknown is not drawn, and the inner one behind it is."""
    path = tmp_path / "block.rrd"
    cells = np.argwhere(np.ones((6, 6, 6), bool))
    trust = np.full(len(cells), 2, dtype=np.uint8)
    trust[np.all(cells == (0, 2, 2), axis=1)] = 0
    with RerunRecorder(path) as rec:
        rec.log_belief(0.0, (cells + 0.5) * 0.1, trust, 0.1)
    row = [r for r in read_rows(path)["/world/belief"] if "Boxes3D:centers" in r][0]
    drawn = np.floor(np.array(row["Boxes3D:centers"]) / 0.1).astype(int)
    assert len(drawn) == len(row["Boxes3D:class_ids"]) == 6**3 - 4**3
    np.testing.assert_allclose(row["Boxes3D:half_sizes"], [[0.05, 0.05, 0.05]])
    inner = drawn[np.all((drawn >= 1) & (drawn <= 4), axis=1)]
    assert inner.tolist() == [[1, 2, 2]], "the inner voxel behind the unknown one, only"


def test_closed_recorder_and_bad_input(tmp_path):
    rec = RerunRecorder(tmp_path / "x.rrd")
    with pytest.raises(ConfigError, match="level"):
        rec.log_event(0.0, "x", level="LOUD")
    with pytest.raises(ConfigError, match="resolution"):
        rec.log_belief(0.0, np.zeros((1, 3)), np.ones(1, dtype=np.uint8), 0.0)
    rec.close()
    with pytest.raises(SimulationError, match="closed"):
        rec.log_scalar(0.0, "speed", 1.0)
    with pytest.raises(ConfigError, match="folder"):
        RerunRecorder(tmp_path / "missing" / "x.rrd")


def test_ellipsoid_axes_reconstruct_random_spd_matrices(rng):
    A = rng.normal(size=(50, 3, 3))
    M = A @ np.swapaxes(A, 1, 2) + 1e-2 * np.eye(3)
    half, quat = ellipsoid_axes(M)
    R = Rotation.from_quat(quat).as_matrix()
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(R @ (half[:, :, None] * np.swapaxes(R, 1, 2)), M, atol=1e-10)
