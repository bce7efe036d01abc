"""The RETREAT mode: a robot at rest whose body overlaps a known obstacle backs off it through
places shown free, checked at every step (secure3d.simulation.retreat)."""

from __future__ import annotations

import numpy as np
import pytest

import secure3d
from secure3d.dynamics.point_mass import PointMass
from secure3d.errors import SimulationError
from secure3d.mapping import OccupancyMap
from secure3d.reactive.controllers import BrakingController
from secure3d.simulation.retreat import (
    RETREAT_MARGINS,
    Retreat,
    bisector_clear,
    plan_retreat,
    unseen_voxels,
)
from secure3d.simulation.tracking import make_tracker

MARGIN = 0.02
BOUNDS = (np.array([-1.0, -1.0, -1.0]), np.array([3.0, 2.0, 2.0]))


def _vertices(lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(8, 3) corners of the box lo..hi."""
    return np.array(
        [
            [(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]]
            for i in (0, 1)
            for j in (0, 1)
            for k in (0, 1)
        ]
    )


def test_the_bisector_test_is_exact_for_boxes(rng):
    """A box passes for a point when every point of it (its corners attain the worst) is at least
    as far from the point as from the anchor, or it lies a radius away; and only then."""
    anchor = np.zeros(3)
    for _ in range(400):
        lo = rng.uniform(-0.5, 0.5, 3)
        hi = lo + rng.uniform(0.01, 0.3, 3)
        p = rng.normal(scale=0.1, size=3)
        got = bisector_clear(p[None], anchor, 0.2, lo[None], hi[None])[0]
        inside = rng.uniform(lo, hi, size=(200, 3))
        pts = np.vstack([_vertices(lo, hi), inside])
        behind = np.all(
            np.linalg.norm(pts - p, axis=1) >= np.linalg.norm(pts - anchor, axis=1) - 1e-12
        )
        far = np.linalg.norm(p - np.clip(p, lo, hi)) >= 0.2
        corners = _vertices(lo, hi)
        exact = far or np.all(
            np.linalg.norm(corners - p, axis=1) >= np.linalg.norm(corners - anchor, axis=1) - 1e-12
        )
        assert got == exact
        if got and not far:
            assert behind
    # the anchor itself is always a place the body may be; no boxes, nothing to refuse
    assert bisector_clear(anchor[None], anchor, 0.2, lo[None], hi[None])[0]
    assert bisector_clear(p[None], anchor, 0.2, np.empty((0, 3)), np.empty((0, 3)))[0]
    with pytest.raises(SimulationError, match="points"):
        bisector_clear(np.array([[np.nan, 0.0, 0.0]]), anchor, 0.2, lo[None], hi[None])


def _wall_map(look_back: bool) -> OccupancyMap:
    """A wall whose surface is at x = 1.095, inside the voxel layer 1.0..1.1, scanned from
    (0.8, 0.55, 0.55), where the robot rests; with ``look_back`` also the space all round it."""
    m = OccupancyMap(0.1, bounds=BOUNDS)
    y, z = np.meshgrid(np.linspace(0.0, 1.1, 45), np.linspace(0.0, 1.1, 45))
    origin = np.array([0.8, 0.55, 0.55])
    wall = np.stack([np.full(y.size, 1.095), y.ravel(), z.ravel()], axis=1)
    m.insert_point_cloud(wall, origin)
    if look_back:  # rays all round, to the wall or 1.5 m
        d = np.random.default_rng(1).normal(size=(40000, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        with np.errstate(divide="ignore"):
            to_wall = np.where(d[:, 0] > 0, (1.095 - origin[0]) / d[:, 0], np.inf)
        m.insert_point_cloud(origin + d * np.minimum(1.5, to_wall)[:, None], origin)
    return m


def test_a_body_overlapping_a_wall_backs_off_it_through_space_seen_free():
    model = PointMass()
    m = _wall_map(look_back=True)
    lo, hi = m.known_obstacle_boxes(include_bounds=False)
    x = model.rest_state([0.81, 0.55, 0.55])  # 0.19 m from the wall's voxels, 0.085 m from it
    rt = plan_retreat(model, x, 2.0, (lo, hi), MARGIN, m, BOUNDS)
    assert rt is not None
    np.testing.assert_allclose(rt.direction, [-1.0, 0.0, 0.0], atol=1e-9)
    want = model.body_radius + RETREAT_MARGINS * MARGIN
    end_clear = np.linalg.norm(rt.end - np.clip(rt.end, lo, hi), axis=1).min()
    assert want <= end_clear < want + 0.003
    # the reference starts and ends at rest at the anchor and the end
    x0, _ = rt.reference(model, rt.start)
    x1, _ = rt.reference(model, rt.start + rt.duration)
    np.testing.assert_allclose(x0[:6], [*rt.anchor, 0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(x1[:6], [*rt.end, 0, 0, 0], atol=1e-12)
    # flown with the real tracker and checked at every step, it ends where it was to end
    tracker, brake, dt, t = make_tracker(model), BrakingController(model), 0.01, rt.start
    while not rt.done(model, x, t, 0.05):
        u, why = rt.control(model, tracker, brake, x, t, dt)
        assert why is None, f"refused at t={t:.2f}: {why}"
        x, t = model.step(x, u, dt), t + dt
    assert np.linalg.norm(x[:3] - rt.end) < 0.01
    # a body already clear of the wall has nothing to back off from
    assert plan_retreat(model, model.rest_state(rt.end), 2.0, (lo, hi), MARGIN, m, BOUNDS) is None


@pytest.mark.parametrize("vehicle", ["quadrotor", "diff_drive"])
def test_every_vehicle_backs_off_with_its_own_tracker(vehicle):
    """A quadrotor flies the retreat level; a diff drive facing the wall reverses along its
    heading, and one parallel to it turns on the spot first (the closed loop turns it)."""
    from secure3d.dynamics.diff_drive import DiffDrive
    from secure3d.dynamics.quadrotor import Quadrotor

    model = Quadrotor() if vehicle == "quadrotor" else DiffDrive()
    m = _wall_map(look_back=True)
    lo, hi = m.known_obstacle_boxes(include_bounds=False)
    x = model.rest_state([0.81, 0.55, 0.5])
    rt = plan_retreat(model, x, 0.0, (lo, hi), MARGIN, m, BOUNDS)
    np.testing.assert_allclose(rt.direction, [-1.0, 0.0, 0.0], atol=1e-9)
    assert not rt.turn and rt.yaw == 0.0  # a diff drive reverses, facing the wall
    tracker, brake, dt, t = make_tracker(model), BrakingController(model), 0.01, 0.0
    while not rt.done(model, x, t, 0.05):
        u, why = rt.control(model, tracker, brake, x, t, dt)
        assert why is None, f"refused at t={t:.2f}: {why}"
        x, t = model.step(x, u, dt), t + dt
    assert np.linalg.norm(np.asarray(model.position(x)).ravel() - rt.end) < 0.01
    if vehicle == "diff_drive":
        side = model.rest_state([0.81, 0.55, 0.5], np.pi / 2)
        rt = plan_retreat(model, side, 0.0, (lo, hi), MARGIN, m, BOUNDS)
        assert rt.turn and abs(np.cos(rt.yaw)) == pytest.approx(1.0)
        np.testing.assert_allclose(rt.direction, [-1.0, 0.0, 0.0], atol=1e-9)


def test_no_retreat_into_space_no_view_shows_free():
    """The same robot, but the camera never saw behind it: the voxels its body would move into
    are unknown, and an obstacle there could be in reach."""
    model = PointMass()
    m = _wall_map(look_back=False)
    lo, hi = m.known_obstacle_boxes(include_bounds=False)
    x = model.rest_state([0.81, 0.55, 0.55])
    assert plan_retreat(model, x, 2.0, (lo, hi), MARGIN, m, BOUNDS) is None
    # ... unless that space is the start region observed before take-off
    seen = (np.array([0.0, 0.0, 0.0]), np.array([1.0, 1.1, 1.1]))
    rt = plan_retreat(model, x, 2.0, (lo, hi), MARGIN, m, BOUNDS, seen=seen)
    assert rt is not None
    unseen_lo, unseen_hi = unseen_voxels(m, rt.anchor, 0.3, seen)
    in_seen = np.all((unseen_lo >= seen[0] - 1e-9) & (unseen_hi <= seen[1] + 1e-9), axis=1)
    centres = unseen_lo + 0.05
    assert np.all(m.is_known_obstacle(centres[in_seen])), "inside the start region only obstacles"
    assert len(unseen_voxels(m, rt.anchor, 0.3)[0]) > len(unseen_lo)
    # a voxel only partly inside the region is not seen: its other part was not observed
    part = (np.array([0.55, 0.0, 0.0]), np.array([1.0, 1.1, 1.1]))
    p_lo, _ = unseen_voxels(m, rt.anchor, 0.3, part)
    assert np.any(np.isclose(p_lo[:, 0], 0.5)) and not np.any(np.isclose(unseen_lo[:, 0], 0.5))


class _Shove:
    """A tracker that pushes towards the wall at full acceleration."""

    def control(self, x, x_ref, u_ref):
        return np.array([4.0, 0.0, 0.0, 0.0])


def test_a_step_that_would_leave_the_checked_places_is_refused():
    model = PointMass()
    m = _wall_map(look_back=True)
    lo, hi = m.known_obstacle_boxes(include_bounds=False)
    x = model.rest_state([0.81, 0.55, 0.55])
    rt = plan_retreat(model, x, 0.0, (lo, hi), MARGIN, m, BOUNDS)
    brake = BrakingController(model)
    assert "no view shows free" in rt.control(model, _Shove(), brake, x, 0.0, 0.01)[1]
    assert rt.control(model, make_tracker(model), brake, x, 0.0, 0.01)[1] is None
    assert "no view shows free" in rt.refusal(np.array([[0.82, 0.55, 0.55]]))  # to the wall
    assert "stray" in rt.refusal(np.array([[0.75, 0.62, 0.55]]))
    assert "leave the map" in rt.refusal(np.array([[0.7, 0.55, 1.85]]))
    assert isinstance(rt, Retreat)


@pytest.mark.slow
def test_a_robot_braked_onto_a_fences_voxels_backs_off_and_arrives(maps_dir, tmp_path):
    """Fence variant 0 of blind_corner (seed 3307): the tracking guard hands the robot to the
    brakes above a low fence; it stops 0.19991 m from the fence's voxels (body radius 0.2 m) and
    every plan from there was refused as starting inside a known obstacle: it held for the rest of
    the run. Now it backs off and flies on to the goal."""
    from secure3d.simulation.campaign_run import plan_campaign
    from secure3d.simulation.closed_loop import simulate
    from secure3d.world.families import variant_rng

    base = secure3d.load_scenario(maps_dir / "blind_corner.yaml")
    options = {"plan_budget": 10.0}
    camp = plan_campaign(base, 1, ["secure"], 3307, tmp_path, "fence", 1, None, None, options)
    scenario = camp.family.variant(camp.prepared, base, variant_rng(3307, 0), 0)
    run = simulate(scenario, "secure", seed=3307, plan_budget=10.0, replan_defer=camp.replan_defer)
    kinds = [e.kind for e in run.events]
    assert not run.collided and run.min_clearance > 0.0, run.summary()
    if "retreat" not in kinds:
        pytest.skip("the variant no longer brakes onto the fence's voxels")
    i = kinds.index("retreat")
    assert "backed off" in kinds[i:] and kinds[i + 1 :].count("retreat") == 0
    assert run.reached_goal, run.summary()


def test_a_turn_before_a_retreat_that_does_not_settle_is_given_up():
    """A wheeled robot turns on the spot before it drives along the line; if the turn has not
    settled RETREAT_TURN_TIME s after the retreat was planned, it gives the retreat up and brakes."""
    import types

    from secure3d.dynamics.diff_drive import DiffDrive
    from secure3d.simulation.at_rest import RETREAT_TURN_TIME, AtRest
    from secure3d.simulation.modes import Mode

    model = DiffDrive()
    m = _wall_map(look_back=True)
    lo, hi = m.known_obstacle_boxes(include_bounds=False)
    side = model.rest_state([0.81, 0.55, 0.5], np.pi / 2)
    rt = plan_retreat(model, side, 0.0, (lo, hi), MARGIN, m, BOUNDS)
    assert rt.turn
    events = []
    flight = types.SimpleNamespace(
        retreat=rt,
        loop=types.SimpleNamespace(brake=BrakingController(model)),
        model=model,
        x=side,
        s=types.SimpleNamespace(dt=0.01),
        mode=Mode.RETREAT,
        event=lambda kind, detail="", level="INFO": events.append((kind, detail)),
    )
    from secure3d.simulation.flight import Flight

    flight.go = lambda trigger: Flight.go(flight, trigger)
    flight.act_brake = lambda: "braking"
    flight.stop_retreat = lambda why: AtRest.stop_retreat(flight, why)
    flight.t = 1.0  # still turning: the turn-in-place control, the retreat kept
    u = AtRest.act_retreat(flight)
    assert np.shape(u) == (model.nu,) and flight.retreat is rt and not events
    flight.t = RETREAT_TURN_TIME + 0.5  # too long
    assert AtRest.act_retreat(flight) == "braking"
    assert flight.retreat is None and flight.mode is Mode.BRAKE
    assert events and events[0][0] == "retreat stopped" and "did not settle" in events[0][1]


def test_bad_input_is_refused_by_name():
    from secure3d.simulation.explore import goal_unseen, viewpoint_for_goal

    model = PointMass()
    m = _wall_map(look_back=True)
    lo, hi = m.known_obstacle_boxes(include_bounds=False)
    with pytest.raises(SimulationError, match="plan_retreat: x must be 7"):
        plan_retreat(model, np.zeros(3), 0.0, (lo, hi), MARGIN, m, BOUNDS)
    with pytest.raises(SimulationError, match="plan_retreat: margin"):
        plan_retreat(model, model.rest_state([0.81, 0.55, 0.55]), 0.0, (lo, hi), -1.0, m, BOUNDS)
    with pytest.raises(SimulationError, match="viewpoint_for_goal: goal"):
        viewpoint_for_goal(None, m, np.zeros(3), [np.nan, 0.0, 0.0])
    with pytest.raises(SimulationError, match="goal_unseen: goal"):
        goal_unseen(None, m, [1.0, 2.0])
