"""``secure3d.simulate``: the paper's Algorithm 1 in closed loop, against the true world.

Reads like the block diagram::

    plan  <- solve(belief)                               # line 1 of Algorithm 1
    loop:  u <- tracker(x, plan(t))                       # follow the plan
           x <- vehicle.step(x, u)                        # RK4, fixed step
           at each camera frame: depth <- ray cast(truth); belief <- insert(depth)
           if the frame revealed an unknown obstacle and the rest of the plan is no longer safe:
               u <- reactive controller pi(x, O) until at rest  # the evasive manoeuvre
               plan <- solve(belief) from the current state     # "go to line 1"
    collisions: swept body capsule between steps vs the true world (python-fcl)

A solver failure is never a reason to continue on an uncertified plan: the robot brakes and retries.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from secure3d.errors import SimulationError
from secure3d.outputs import check_output_path
from secure3d.planning.result import finite_or_none

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.result import PlanResult
    from secure3d.world.spec import Scenario

#: Hits are inserted this far (m) in front of the surface they were measured on.
SURFACE_BIAS = 1e-4
#: The robot counts as stopped below this speed (m/s) before it replans.
STOP_SPEED = 0.05
#: Goal reached: within the goal tolerance and slower than this (m/s).
ARRIVAL_SPEED = 0.25
#: Wall-clock seconds between the INFO lines ``simulate`` logs while it flies (logger
#: ``secure3d.simulation``), so a long run always says where it is.
HEARTBEAT_SECONDS = 10.0
#: Events go out at DEBUG, the heartbeat at INFO.
log = logging.getLogger("secure3d.simulation")

#: Points sampled along a colliding step for the clearance it reached (a 0.01 s step at 5 m/s is
#: 5 cm long: 11 points sample it every 5 mm).
CONTACT_SAMPLES = 11
#: Seconds between retries of a failed replan (the robot holds still meanwhile).
REPLAN_RETRY = 0.5
#: Cruise-speed fractions of the initial guess for successive failed replans at rest: the map and
#: the state are unchanged between retries, so the same guess would fail the same way.
RETRY_SPEEDS = (0.8, 0.4, 1.0, 0.2)
#: Failed replans in a row at rest after which the robot, having tried every retry start, turns
#: to look around once (new views can change the problem; the same problem fails the same way),
#: and twice that many after which it stops replanning and holds still. (A hidden-obstacle
#: variant cycled through the same four failures 25 times, 80 s of wall time, before.)
STUCK_RETRIES = len(RETRY_SPEEDS)
#: Fraction of the model's yaw-rate limit used to look around at rest, and the yaw error (rad) at
#: which a look-around heading counts as reached.
SCAN_RATE_FRACTION = 0.8
SCAN_TOLERANCE = 0.05


@dataclass(frozen=True)
class SimEvent:
    """Something that happened during a run, at simulation time ``time`` (s)."""

    time: float
    kind: str
    detail: str = ""

    def __str__(self) -> str:
        return f"[{self.time:6.2f}s] {self.kind}: {self.detail}"


@dataclass(frozen=True, eq=False)
class SimResult:
    """Outcome of one closed-loop run.

    Attributes
    ----------
    collided, collision_time, collision_obstacles : whether and when the body touched the true world.
    reached_goal, time_to_goal : arrival at rest within the goal tolerance.
    min_clearance : smallest body-to-world distance over the run (m), the colliding step included
        (then <= 0: minus the deepest penetration sampled along that step).
    times (T,), states (T, nx), positions (T, 3), speeds (T,) : the realised motion.
    events : frames with detections, take-overs, replans, failures, in order.
    plans : (time, PlanResult) of every plan followed.
    detection_time, detection_point : first frame that saw a hidden obstacle, and where the robot was.
    frames, takeovers, replans : counts. solve_times : wall time of every plan call (s).
    wall_time : the whole run's wall time (s), set-up included.
    setup_time : the part of it spent before take-off: building the true world, the camera, the
        collision world and the belief map, compiling the NLP (unless already cached), and opening
        the recording (``rrd``).
    flight_time : the rest: every frame, map update, plan (the first one included), re-certification,
        tracking step and collision check. real_time_factor = simulated time / flight_time.
    """

    scenario: str
    planner: str
    seed: int
    collided: bool
    collision_time: float | None
    collision_obstacles: tuple[str, ...]
    reached_goal: bool
    time_to_goal: float | None
    min_clearance: float
    times: np.ndarray
    states: np.ndarray
    positions: np.ndarray
    speeds: np.ndarray
    events: tuple[SimEvent, ...]
    plans: tuple[tuple[float, PlanResult], ...]
    detection_time: float | None
    detection_point: np.ndarray | None
    frames: int
    takeovers: int
    replans: int
    solve_times: tuple[float, ...]
    wall_time: float
    setup_time: float = 0.0
    outputs: dict[str, Path] = field(default_factory=dict)

    @property
    def sim_time(self) -> float:
        return float(self.times[-1]) if len(self.times) else 0.0

    @property
    def flight_time(self) -> float:
        return self.wall_time - self.setup_time

    def to_dict(self) -> dict[str, object]:
        """The run as JSON-ready data for scripts (``secure3d simulate --json``): outcome, times,
        clearance, counts, events and each followed plan's :meth:`PlanResult.to_dict`; no arrays."""
        num = finite_or_none
        return {
            "scenario": self.scenario,
            "planner": self.planner,
            "seed": int(self.seed),
            "outcome": self.outcome,
            "collided": bool(self.collided),
            "collision_time": None if self.collision_time is None else num(self.collision_time),
            "collision_obstacles": list(self.collision_obstacles),
            "reached_goal": bool(self.reached_goal),
            "time_to_goal": None if self.time_to_goal is None else num(self.time_to_goal),
            "min_clearance": num(self.min_clearance),
            "detection_time": None if self.detection_time is None else num(self.detection_time),
            "sim_time": num(self.sim_time),
            "frames": int(self.frames),
            "takeovers": int(self.takeovers),
            "replans": int(self.replans),
            "wall_time": num(self.wall_time),
            "setup_time": num(self.setup_time),
            "real_time_factor": num(self.real_time_factor),
            "events": [
                {"time": num(e.time), "kind": e.kind, "detail": e.detail} for e in self.events
            ],
            "plans": [{"time": num(t), **p.to_dict()} for t, p in self.plans],
            "outputs": {k: str(v) for k, v in self.outputs.items()},
        }

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second of flight (set-up apart, as a robot compiles its
        planner before take-off; see ``setup_time``)."""
        return self.sim_time / max(self.flight_time, 1e-9)

    @property
    def outcome(self) -> str:
        if self.collided:
            return "collided"
        if self.reached_goal:
            return "reached goal"
        if not self.plans:
            return "no plan"
        return "did not arrive"

    def summary(self) -> str:
        """A few readable lines."""
        goal = f"{self.time_to_goal:.2f} s" if self.time_to_goal is not None else "-"
        det = f"{self.detection_time:.2f} s" if self.detection_time is not None else "never"
        solve = f"{1e3 * np.median(self.solve_times):.0f} ms median" if self.solve_times else "-"
        return (
            f"{self.scenario} / {self.planner}: {self.outcome.upper()}"
            + (
                f" with {', '.join(self.collision_obstacles)} at t={self.collision_time:.2f} s"
                if self.collided
                else ""
            )
            + f"\n  time to goal {goal}, min clearance {self.min_clearance:.3f} m, hidden obstacle seen {det}"
            + f"\n  frames {self.frames}, take-overs {self.takeovers}, replans {self.replans}, solves {solve}"
            + f"\n  simulated {self.sim_time:.2f} s in {self.flight_time:.2f} s of flight"
            + f" ({self.real_time_factor:.1f}x real time), after {self.setup_time:.2f} s of set-up"
        )


#: The certificate's sampling step (s): a manoeuvre that fails at plan time t_bad leaves the robot
#: until t_bad minus this to switch to a new plan.
CERT_STEP = 0.02

#: Obstacle slots per node in closed loop (the planner's default is 8; see ``_Loop``).
CLOSED_LOOP_OBSTACLE_SLOTS = 12


class _Loop:
    """State of one closed-loop run (kept out of SimResult so the result stays plain data)."""

    def __init__(
        self, scenario: Scenario, planner: str, seed: int, options: dict, cache: object
    ) -> None:
        from secure3d.planning.problem import problem_from_scenario
        from secure3d.planning.solve import DEFAULT_CACHE
        from secure3d.reactive.controllers import BrakingController
        from secure3d.simulation.camera import DepthCamera
        from secure3d.simulation.collision import CollisionWorld
        from secure3d.simulation.scene import world_trimesh
        from secure3d.simulation.tracking import make_tracker
        from secure3d.world.attacks import belief_map, true_obstacles

        self.scenario = scenario
        self.planner = planner
        self.truth = true_obstacles(scenario)
        try:
            mesh = world_trimesh(self.truth.boxes, self.truth.meshes, self.truth.voxel_boxes)
            self.camera = DepthCamera(scenario.camera, mesh, rng=np.random.default_rng(seed))
            self.collision = CollisionWorld(
                self.truth.boxes, self.truth.meshes, self.truth.voxel_boxes
            )
        except (ValueError, RuntimeError) as exc:
            raise SimulationError(f"{scenario.name}: cannot build the true world: {exc}") from exc
        self.belief = belief_map(scenario)
        # every replan brings a new look-back assignment: one compiled NLP for all of them
        options.setdefault("lookback_encoding", "parameter")
        # Sensed surfaces reach the planner as many small boxes: with 8 slots per node most
        # replans in flight re-selected slots and re-solved 3 times (8 hidden-obstacle variants:
        # 0.44x real time with 8 slots, 0.52x with 10, 0.54x with 12, 0.26x with 16).
        options.setdefault("obstacle_slots", CLOSED_LOOP_OBSTACLE_SLOTS)
        # no obstacle boxes yet: the first frame goes into the map before the first plan, which
        # merges them (:meth:`refresh_obstacles`)
        no_boxes = (np.empty((0, 3)), np.empty((0, 3)))
        self.problem = problem_from_scenario(
            scenario, belief=self.belief, obstacle_boxes=no_boxes, **options
        )
        self.model = self.problem.model
        self.brake = BrakingController(self.model)
        self.tracker = make_tracker(self.model)
        # the planner's module-wide cache by default: runs in one process share compiled NLPs
        self.cache = cache if cache is not None else DEFAULT_CACHE
        # Compile the NLP before take-off, as a robot would (part of the set-up; see simulate). A
        # look-back assignment compiled into the structure is known only at plan time: then the
        # first plan compiles it, in flight.
        self.cache.prepare(self.problem, planner)
        self.hidden = set(scenario.hidden_obstacles)
        self.start_problem = self.problem
        self.first_problem = self.problem  # its start region was observed before take-off
        #: per plan re-certified in flight (by id, the last few): its sampled manoeuvres, the boxes
        #: it last passed against and what observed its manoeuvre points then (:func:`_plan_unsafe`)
        self.rechecks: OrderedDict[int, _Recheck] = OrderedDict()
        # obstacle boxes the plan being followed was last planned or certified against
        self.judged_lo: np.ndarray | None = None
        self.judged_hi: np.ndarray | None = None

    def refresh_obstacles(self) -> None:
        lo, hi = self.belief.known_obstacle_boxes(close_gaps=self.problem.options.close_gaps)
        self.problem = dataclasses.replace(self.problem, boxes_lo=lo, boxes_hi=hi)

    def judged_against_current(self) -> None:
        """The plan being followed is now known safe against the current obstacle boxes."""
        self.judged_lo, self.judged_hi = self.problem.boxes_lo, self.problem.boxes_hi

    def judged_plus(self, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The judged boxes plus the voxels at ``centres`` (merged into few boxes): a superset of
        the known obstacles when ``centres`` are all the known obstacle voxels found outside the
        judged boxes since they were set (see :func:`_new_obstacle_voxels`). Certifying against it
        is sound (more obstacles never help a plan) and needs no re-merge of the whole map."""
        from secure3d.geometry.box_index import BoxIndex
        from secure3d.mapping.boxes import merge_cells

        res = self.belief.resolution
        klo, khi = merge_cells(np.floor(centres / res).astype(np.int64))
        # the spatial index of the judged boxes, extended by the new ones (no rebuild); problems on
        # these boxes find it by content (BoxIndex.of)
        index = BoxIndex.of(self.judged_lo, self.judged_hi).extended(klo * res, (khi + 1) * res)
        return index.lo, index.hi


def _voxel_colors(scenario: Scenario) -> np.ndarray | None:
    """r, g, b of ``world.octomap``'s voxels for a colour tree, else None."""
    from secure3d.world.attacks import octomap_voxel_colors

    w = scenario.world
    return None if w.octomap is None else octomap_voxel_colors(w.octomap, "world.octomap")


def _voxel_drawing(scenario: Scenario, loop: _Loop) -> dict:
    """Keyword arguments drawing ``world.octomap``'s voxels (in a colour tree's colours) and the
    server map's claimed voxels when it is a file or is attacked by region."""
    from secure3d.world.attacks import server_claim

    claim = server_claim(scenario)
    file_claim = claim.bt is not None or claim.cloud is not None or claim.mesh is not None
    claimed = None
    if file_claim or claim.regions:
        from secure3d.world.attacks import belief_map

        claimed = belief_map(scenario).claimed_voxels(True)
    return {
        "voxel_boxes": loop.truth.voxel_boxes,
        "voxel_colors": _voxel_colors(scenario),
        "claimed_voxels": claimed,
        "voxel_size": scenario.server_map.resolution,
    }


def _new_obstacle_voxels(loop: _Loop, occupied_codes: np.ndarray) -> np.ndarray:
    """Centres ``(n, 3)`` of the known obstacle voxels among those a frame (already inserted)
    updated as occupied (``occupied_codes``, Morton codes) that the boxes the current plan was last
    judged against do not cover.

    Only a hit can make a voxel a known obstacle (misses only ever free voxels, which shrinks the
    obstacle set and so cannot break a plan: fewer obstacles never block a view or a manoeuvre). So
    if every known obstacle voxel this frame hit is covered, the obstacle set is still inside the
    judged boxes and the plan stays certified; otherwise the frame revealed something new. Voxels
    that merely flicker (hit, then carved by grazing rays) are not news unless they end up occupied.
    """
    if loop.judged_lo is None or not len(occupied_codes):
        return np.empty((0, 3))
    from secure3d.geometry.box_index import BoxIndex
    from secure3d.mapping.keys import codes_to_coords

    known = occupied_codes[loop.belief.is_known_obstacle_sensed(occupied_codes)]
    centres = codes_to_coords(known, loop.belief.resolution)
    if not len(centres):
        return centres
    return centres[~BoxIndex.of(loop.judged_lo, loop.judged_hi).inside_any(centres)]


def observed_box(
    belief: object,
    centre: np.ndarray,
    half_max: float,
    assumed: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray] | None:
    """The largest box of whole voxels around ``centre`` (each face at most ``half_max`` from it) in
    which every voxel was seen by the camera or is a known obstacle: the start region of a replan
    in flight. Unknown and merely *claimed* free space never counts as observed (the server may
    lie). Faces grow one voxel layer at a time, in turn, while the new layer is all observed, so the
    box stretches along a corridor even when the floor and ceiling near the robot were never in
    view. Voxels inside ``assumed`` (lo, hi) count as observed too: the start region of the flight,
    observed before take-off by the paper's premise. None if the voxel holding ``centre`` itself is
    unobserved.
    """
    from secure3d.mapping.occupancy import Trust

    centre = np.asarray(centre, dtype=float)
    if centre.shape != (3,) or not np.all(np.isfinite(centre)):
        raise SimulationError(f"observed_box: centre must be 3 finite numbers, got {centre!r}")
    if not (np.isfinite(half_max) and half_max >= 0):
        raise SimulationError(f"observed_box: half_max must be a number >= 0, got {half_max!r}")
    res = belief.resolution
    allowed = np.array([Trust.SENSED_FREE, Trust.SENSED_OCCUPIED, Trust.CLAIMED_OCCUPIED])

    def observed(a: np.ndarray, b: np.ndarray) -> bool:  # every voxel a..b (inclusive indices)
        axes = [np.arange(a[d], b[d] + 1) for d in range(3)]
        cells = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        pts = (cells + 0.5) * res
        ok = np.isin(belief.trust(pts), allowed)
        if assumed is not None:
            ok |= np.all((pts >= assumed[0]) & (pts <= assumed[1]), axis=1)
        return bool(ok.all())

    k = np.floor(centre / res).astype(np.int64)
    a, b = k.copy(), k.copy()
    if not observed(a, b):
        return None
    growing = {(d, side) for d in range(3) for side in (-1, 1)}
    while growing:
        for d, side in sorted(growing):
            na, nb = a.copy(), b.copy()
            if side < 0:
                na[d] -= 1
                slab_a, slab_b, reach = na.copy(), b.copy(), centre[d] - na[d] * res
                slab_b[d] = na[d]
            else:
                nb[d] += 1
                slab_a, slab_b, reach = a.copy(), nb.copy(), (nb[d] + 1) * res - centre[d]
                slab_a[d] = nb[d]
            if reach > half_max + 1e-9 or not observed(slab_a, slab_b):
                growing.discard((d, side))
            else:
                a, b = na, nb
    return a * res, (b + 1) * res


def scan_headings(yaw: float, hfov: float) -> list[float]:
    """Headings a stopped robot turns through before it replans: half a field of view to either
    side and back, so that it has seen a field of view and a half around where it was looking.

    A take-over happens because the camera revealed part of an obstacle the plan did not know; the
    rest of it often lies just outside the frame. Looking around at rest costs a second or two but
    lets the replan see that rest instead of planning into it and taking over again (the paper's
    Algorithm 1 replans at once; this is a liveness addition that never moves the robot)."""
    if not (np.isfinite(yaw) and np.isfinite(hfov) and 0 < hfov < 2 * np.pi):
        raise SimulationError(
            f"scan_headings: need a finite yaw and 0 < hfov < 2 pi, got {yaw!r}, {hfov!r}"
        )
    half = 0.5 * hfov
    return [yaw + half, yaw - half, yaw]


def _heading_error(target: float, yaw: float) -> float:
    """``target - yaw`` wrapped to (-pi, pi] (rad)."""
    return float(np.angle(np.exp(1j * (target - yaw))))


def _scan_control(
    model: object, brake: object, x: np.ndarray, target: float, dt: float
) -> np.ndarray:
    """Hold still (the braking law) while turning the heading towards ``target``."""
    u = np.array(brake.control(x), dtype=float)
    err = _heading_error(target, float(model.yaw(x)))
    name = getattr(model, "name", "")
    if name == "diff_drive":
        lim = model.limits
        rate = float(np.clip(3.0 * err, -1, 1)) * SCAN_RATE_FRACTION * lim.max_ang_speed
        u[1] = np.clip((rate - float(x[4])) / dt, -lim.max_ang_accel, lim.max_ang_accel)
    else:  # point mass (yaw rate) and quadrotor (body z rate, level at rest)
        w = SCAN_RATE_FRACTION * model.limits.max_yaw_rate
        u[3] = float(np.clip(3.0 * err, -w, w))
    return u


def _path_clearance(
    loop: _Loop, plan: PlanResult, t_rel: float, lo: np.ndarray, hi: np.ndarray
) -> float:
    """Smallest distance from the rest of the planned body path to the boxes, minus the body radius."""
    from secure3d.geometry.box_index import BoxIndex
    from secure3d.planning.trajectory import interpolate

    t = np.arange(t_rel, plan.final_time, 0.02)
    if len(t) == 0 or len(lo) == 0:
        return float("inf")
    X, _ = interpolate(loop.model, plan.times, plan.states, plan.controls, t)
    P = np.asarray(loop.model.position(X), dtype=float)
    # 0 inside a box, as the body is then simply in contact
    dist = BoxIndex.of(lo, hi).min_distance(P)
    return float(np.maximum(dist, 0.0).min() - loop.model.body_radius)


@dataclass(eq=False)
class _Recheck:
    """A plan being re-certified in flight: its sampled manoeuvres (map-independent), the obstacle
    boxes it last passed against and what observed each manoeuvre point then (``Certificate.views``;
    None until it first passed)."""

    plan: PlanResult
    sampled: object
    views: np.ndarray | None = None
    lo: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    hi: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


def _plan_unsafe(
    loop: _Loop,
    plan: PlanResult,
    plan_problem_: object,
    t_rel: float,
    lo: np.ndarray,
    hi: np.ndarray,
) -> tuple[str, float] | None:
    """Why the rest of ``plan`` (from ``t_rel`` on) is not safe among the obstacle boxes ``lo, hi``
    (the updated belief), and the plan time from which it is not (the first manoeuvre that fails
    the certificate; ``inf`` for the baseline, which promises no manoeuvre), or None.
    ``plan_problem_`` is the problem the plan was planned (and certified) on.

    A secure plan that already passed against a prefix of these boxes (the boxes only grew, as
    :meth:`_Loop.judged_plus` grows them) is judged against the added boxes alone first
    (:func:`~secure3d.planning.certificate.views_after_adding`, sound); the full certificate runs
    only if that does not show it safe."""
    from secure3d.planning.certificate import certify, sample_plan, views_after_adding

    if loop.planner == "secure":
        judged = dataclasses.replace(plan_problem_, boxes_lo=lo, boxes_hi=hi)
        rec = loop.rechecks.get(id(plan))
        if rec is None or rec.plan is not plan:
            cert = plan.certificate
            if cert is not None and cert.ok and cert.sampled is not None:
                # certified when planned, against the boxes of the problem it was planned on
                rec = _Recheck(
                    plan, cert.sampled, cert.views, plan_problem_.boxes_lo, plan_problem_.boxes_hi
                )
            else:
                rec = _Recheck(plan, sample_plan(plan, judged))
            loop.rechecks[id(plan)] = rec
            while len(loop.rechecks) > 4:
                loop.rechecks.popitem(last=False)
        n = len(rec.lo)
        if rec.views is not None and (
            len(lo) >= n and np.array_equal(lo[:n], rec.lo) and np.array_equal(hi[:n], rec.hi)
        ):
            # the boxes only grew since the plan last passed: check what the new ones touch
            views = views_after_adding(rec.views, rec.sampled, judged, lo[n:], hi[n:], t_from=t_rel)
            if views is not None:
                rec.views, rec.lo, rec.hi = views, lo, hi
                return None
        cert = certify(plan, judged, t_from=t_rel, sampled=rec.sampled)
        if cert.ok:
            rec.views, rec.lo, rec.hi = cert.views, lo, hi
            return None
        first = cert.first_violation
        return str(first), float(first.time) if first is not None else t_rel
    # The baseline only promises a collision-free path: react when the new evidence brings an obstacle
    # into the body's planned path.
    after = _path_clearance(loop, plan, t_rel, lo, hi)
    before = _path_clearance(loop, plan, t_rel, plan_problem_.boxes_lo, plan_problem_.boxes_hi)
    if after < 0.0 and after < before - 1e-3:
        return (
            f"an obstacle seen in flight blocks the planned path (clearance {after:+.3f} m)",
            np.inf,
        )
    return None


#: Default ``replan_defer`` of :func:`simulate` (s). Measured on the 200 hidden-obstacle variants of
#: the blind corner: see README ("Closed loop") and ``benchmarks/results/campaign_blind_corner.md``.
DEFAULT_REPLAN_DEFER = 0.5


def replan_defer_for(
    replan_defer: float | None, replan_latency: float, error: type[Exception] = SimulationError
) -> float:
    """The ``replan_defer`` a run uses: as given (checked), or by default
    :data:`DEFAULT_REPLAN_DEFER`, off (0) when a ``replan_latency`` is set, as the two do not
    combine; both set explicitly is an ``error``."""
    if replan_defer is None:
        return 0.0 if replan_latency > 0.0 else DEFAULT_REPLAN_DEFER
    replan_defer = check_replan_seconds("replan_defer", replan_defer, error)
    if replan_defer > 0.0 and replan_latency > 0.0:
        raise error(
            f"replan_defer ({replan_defer}) and replan_latency ({replan_latency}): set one, not both"
        )
    return replan_defer


def check_replan_seconds(
    name: str, value: object, error: type[Exception] = SimulationError
) -> float:
    """``value`` (``replan_latency``, ``replan_defer``) as seconds in [0, 10), else ``error`` naming
    ``name`` and the value."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value < 10.0:
        raise error(f"{name}: seconds in [0, 10), got {value!r}")
    return float(value)


def simulate(
    scenario: Scenario | str | Path,
    planner: str = "secure",
    seed: int = 0,
    rrd: str | Path | None = None,
    png: str | Path | None = None,
    *,
    cache: object | None = None,
    max_replans: int = 25,
    look_around: bool = False,
    replan_in_flight: bool = True,
    replan_latency: float = 0.0,
    replan_defer: float | None = None,
    frame_log_every: int = 2,
    belief_log_every: int = 5,
    **options: object,
) -> SimResult:
    """Fly a scenario in closed loop (the paper's Algorithm 1) and report what happened.

    Parameters
    ----------
    scenario : a Scenario or the path of a scenario YAML file.
    planner : ``"secure"`` or ``"baseline"``.
    seed : seeds the camera noise and dropout (runs are deterministic for a seed).
    rrd : write a Rerun recording of the run there (atomically); replay with ``rerun FILE.rrd``.
    png : write the top-down figure of the run there (atomically).
    cache : an :class:`~secure3d.planning.collocation.NLPCache` for the compiled NLPs (default: the
        planner's module-wide cache, so runs in one process build each NLP shape once).
    max_replans : give up (robot holds still) after this many failed or successful replans. It
        also gives up after ``2 * STUCK_RETRIES`` failed replans in a row at rest, having looked
        around once after ``STUCK_RETRIES`` of them (the same problem fails the same way).
    replan_in_flight : when new evidence breaks the rest of the plan, first try to replan from the
        moving state (the solve takes no simulated time); brake only if that fails.
    replan_latency : simulated seconds a replan in flight takes (default 0: instantaneous). With
        latency L the robot plans from where its current plan puts it L seconds later, keeps
        following that plan meanwhile, and switches at t + L; if the current plan's first
        uncertified manoeuvre comes before the switch, it brakes instead (take-over).
    replan_defer : seconds (default None: :data:`DEFAULT_REPLAN_DEFER`, 0.5 s, or 0 when
        ``replan_latency`` is set; 0: replan at once). When new evidence breaks the plan but its
        first failing manoeuvre is more than this far ahead, keep following the plan (certified up
        to that manoeuvre) and replan this long before it, or sooner if later frames bring it
        closer. A hidden obstacle revealed a few voxels per frame then costs one replan, made with
        more of it seen, instead of one per frame. Not combined with ``replan_latency``.
    look_around : after a take-over (and after every failed replan), turn the camera half a field
        of view to either side at rest before replanning (see :func:`scan_headings`).
    frame_log_every, belief_log_every : decimation of camera frames and belief voxels in the recording.
    **options : planner options (see :class:`~secure3d.planning.problem.PlannerOptions`).
    """
    if isinstance(scenario, (str, Path)):
        from secure3d.world.scenario import load_scenario

        scenario = load_scenario(scenario)
    if planner not in ("secure", "baseline"):
        raise SimulationError(f"planner: must be 'secure' or 'baseline', got {planner!r}")
    replan_latency = check_replan_seconds("replan_latency", replan_latency)
    replan_defer = replan_defer_for(replan_defer, replan_latency)
    # the output contract: a path that cannot be written fails now, not after the flight
    rrd = None if rrd is None else check_output_path(rrd, (".rrd",), "rrd")
    png = None if png is None else check_output_path(png, (".png",), "png")
    wall0 = time.perf_counter()
    loop = _Loop(scenario, planner, seed, dict(options), cache)
    settings = _RunSettings(
        dt=scenario.simulation.dt,
        frame_period=1.0 / scenario.camera.rate_hz,
        goal=np.asarray(scenario.goal.position, dtype=float),
        time_limit=scenario.simulation.time_limit,
        max_replans=max_replans,
        look_around=look_around,
        replan_in_flight=replan_in_flight,
        replan_latency=replan_latency,
        replan_defer=replan_defer,
        frame_log_every=frame_log_every,
        belief_log_every=belief_log_every,
        seed=seed,
        wall0=wall0,
    )

    recorder = None
    if rrd is not None:
        from secure3d.viz.rerun_log import RerunRecorder, recording_id

        recorder = RerunRecorder(rrd, recording_id=recording_id(f"{scenario.name}-{planner}", seed))
    setup_time = time.perf_counter() - wall0  # take-off: the recording is open, the NLP compiled
    try:
        result = _run(loop, recorder, settings)
    except BaseException:
        if recorder is not None:
            recorder.abort()
        raise
    outputs: dict[str, Path] = {}
    if recorder is not None:
        outputs["rrd"] = recorder.close()
    if png is not None:
        from secure3d.viz.figures import top_down_figure

        outputs["png"] = top_down_figure(
            scenario.world.bounds,
            scenario.world.boxes,
            true_meshes=scenario.world.meshes,
            out_path=png,
            hidden_names=scenario.hidden_obstacles,
            plans=[p for _, p in result.plans[:1]],
            realised_paths={planner: result.positions},
            detection_points=[result.detection_point]
            if result.detection_point is not None
            else None,
            start=np.asarray(scenario.start.position),
            goal=settings.goal,
            collision_points=[result.positions[-1]] if result.collided else (),
            title=f"{scenario.name}: {planner} ({result.outcome})",
            **_voxel_drawing(scenario, loop),
        )
    return dataclasses.replace(result, setup_time=setup_time, outputs=outputs)


@dataclass(frozen=True)
class _RunSettings:
    """How one closed-loop run is flown (see :func:`simulate`)."""

    dt: float
    frame_period: float
    goal: np.ndarray
    time_limit: float
    max_replans: int
    look_around: bool
    replan_in_flight: bool
    replan_latency: float
    replan_defer: float
    frame_log_every: int
    belief_log_every: int
    seed: int
    wall0: float


def _run(loop: _Loop, rec: object | None, settings: _RunSettings) -> SimResult:
    from secure3d.planning.solve import plan_problem
    from secure3d.planning.trajectory import Interpolant, interpolate

    scenario, model = loop.scenario, loop.model
    dt, frame_period, goal = settings.dt, settings.frame_period, settings.goal
    max_replans, look_around = settings.max_replans, settings.look_around
    replan_in_flight, seed, wall0 = settings.replan_in_flight, settings.seed, settings.wall0
    latency, defer = settings.replan_latency, settings.replan_defer
    frame_log_every, belief_log_every = settings.frame_log_every, settings.belief_log_every
    time_limit, r = settings.time_limit, model.body_radius
    name = scenario.name
    events: list[SimEvent] = []
    plans: list[tuple[float, PlanResult]] = []
    solve_times: list[float] = []

    def event(t: float, kind: str, detail: str = "", level: str = "INFO") -> None:
        events.append(SimEvent(t, kind, detail))
        log.debug("%s t=%.2f s %s: %s %s", name, t, level, kind, detail)
        if rec is not None:
            rec.log_event(t, f"{kind}: {detail}", level)

    def sense(t: float, x: np.ndarray, frame_no: int) -> tuple[np.ndarray, set[str]]:
        """Capture a frame, insert it, return (centres of the obstacle voxels it revealed outside
        the judged boxes, hidden obstacles seen)."""
        R, o = model.camera_pose(x)
        R, o = np.asarray(R, float), np.asarray(o, float).ravel()
        frame = loop.camera.render(R, o)
        cam = loop.camera
        # Insert hits a hair (0.1 mm) in front of the surface: a wall lying exactly on a voxel
        # boundary then marks the voxel in front of it (which its claim covers) instead of flipping
        # between the two voxels with float rounding and carving the claim into fragments.
        stats = loop.belief.insert_depth_image(
            frame.depth - SURFACE_BIAS,
            (cam.fx, cam.fy, cam.cx, cam.cy),
            R,
            o,
            scenario.camera.max_range,
            discretize=scenario.camera.discretize,
            far_kind=scenario.camera.far_kind,
        )
        new = _new_obstacle_voxels(loop, stats.occupied_codes)
        if rec is not None and frame_no % frame_log_every == 0:
            rec.log_camera(
                t, R, o, cam.fx, cam.fy, scenario.camera.width, scenario.camera.height, frame.depth
            )
        if rec is not None and frame_no % belief_log_every == 0:
            occ, trust = loop.belief.known_obstacles()
            if len(occ):
                rec.log_belief(t, occ, trust, loop.belief.resolution)
        return new, set(frame.hit_names()) & loop.hidden

    failures = [0]  # failed plan calls in a row

    def make_plan(t: float, x: np.ndarray) -> PlanResult | None:
        loop.refresh_obstacles()
        if t == 0.0:
            problem = (
                loop.problem
            )  # the paper's premise: the start region was observed before take-off
        else:
            # In flight only what the camera has actually seen counts as observed around the robot.
            p = np.asarray(model.position(x), dtype=float).ravel()
            first = loop.first_problem
            box = observed_box(
                loop.belief,
                p,
                loop.problem.options.start_region_radius,
                assumed=(first.start_region_lo, first.start_region_hi),
            )
            problem = loop.problem.with_start(x, region=box if box is not None else (p, p))
        if failures[0]:
            speed = RETRY_SPEEDS[failures[0] % len(RETRY_SPEEDS)]
            problem = problem.with_options(guess_speed_fraction=speed)
        loop.start_problem = problem
        t0 = time.perf_counter()
        result = plan_problem(problem, loop.planner, cache=loop.cache)
        solve_times.append(time.perf_counter() - t0)
        if not result.ok:
            failures[0] += 1
            event(t, "plan failed", f"{result.status.value}: {result.message}", "WARN")
            return None
        failures[0] = 0
        plans.append((t, result))
        event(t, "plan", f"T={result.final_time:.2f}s solve={1e3 * solve_times[-1]:.0f}ms")
        if rec is not None:
            rec.log_plan(t, result, label=loop.planner)
            rec.log_scalar(t, "solve_time_ms", 1e3 * solve_times[-1])
        return result

    if rec is not None:
        from secure3d.world.attacks import server_claim

        claim = server_claim(scenario)
        rec.log_world(
            true_boxes=loop.truth.boxes,
            true_meshes=loop.truth.meshes,
            claimed_boxes=claim.boxes,
            claimed_meshes=claim.meshes,
            hidden_names=tuple(loop.hidden),
            bounds=scenario.world.bounds,
            true_voxels=loop.truth.voxel_boxes,
            true_voxel_colors=_voxel_colors(scenario),
        )

    x = np.asarray(loop.problem.x0, dtype=float)
    t = 0.0
    frame_no = 0
    sense(t, x, frame_no)
    next_frame = frame_period
    current = make_plan(0.0, x)
    if current is not None:
        loop.judged_against_current()
    plan_start = 0.0
    plan_problem_snapshot = loop.problem
    mode = "follow" if current is not None else "hold"
    last_attempt = 0.0
    headings: list[float] = []  # look-around headings still to turn to
    reference: tuple = (None, None)  # (plan followed, its Interpolant) for the tracker
    pending = None  # (switch time, plan, its problem): a replan in flight waiting out its latency
    deferred = None  # (due time, (why, t_bad)): a replan in flight put off (``replan_defer``)
    hfov = loop.problem.frustum.hfov
    replans = takeovers = 0
    held_failures = 0  # failed replans in a row at rest (see STUCK_RETRIES)
    detection_time = None
    detection_point = None
    collided = False
    collision_time = None
    collision_names: tuple[str, ...] = ()
    reached = False
    time_to_goal = None
    min_clear = clear = float(loop.collision.clearance(model.position(x), r))
    T_log: list[float] = [t]
    X_log: list[np.ndarray] = [x.copy()]

    n_steps = int(np.ceil(time_limit / dt))
    beat = time.perf_counter()
    for _ in range(n_steps):
        if time.perf_counter() - beat >= HEARTBEAT_SECONDS:
            beat = time.perf_counter()
            log.info(
                "%s: %.2f of at most %.1f s flown in %.0f s of wall time, %d plans so far",
                name,
                t,
                time_limit,
                beat - wall0,
                len(plans),
            )
        # ---- sense ---------------------------------------------------------------------------
        unsafe = None  # (why, plan time of the first failing manoeuvre) when the plan must go
        if t + 1e-9 >= next_frame:
            frame_no += 1
            next_frame += frame_period
            new, hidden_seen = sense(t, x, frame_no)
            if hidden_seen and detection_time is None:
                detection_time, detection_point = t, np.asarray(model.position(x), float).copy()
                event(t, "hidden obstacle seen", ", ".join(sorted(hidden_seen)), "WARN")
            if len(new) and mode == "follow" and current is not None:
                t_rel = t - plan_start
                # First against the judged boxes plus the new voxels (a superset of the known
                # obstacles); only if that fails, against the whole map merged afresh.
                lo, hi = loop.judged_plus(new)
                unsafe = _plan_unsafe(loop, current, plan_problem_snapshot, t_rel, lo, hi)
                broken = None
                if pending is not None:
                    broken = _plan_unsafe(loop, pending[1], pending[2], 0.0, lo, hi)
                if unsafe is not None or broken is not None:
                    loop.refresh_obstacles()
                    lo, hi = loop.problem.boxes_lo, loop.problem.boxes_hi
                    unsafe = _plan_unsafe(loop, current, plan_problem_snapshot, t_rel, lo, hi)
                    if pending is not None:
                        broken = _plan_unsafe(loop, pending[1], pending[2], 0.0, lo, hi)
                if broken is not None:
                    event(t, "pending plan dropped", broken[0], "WARN")
                    pending = None
                    unsafe = unsafe or broken
                if unsafe is None:
                    loop.judged_lo, loop.judged_hi = lo, hi
                    deferred = None
                elif pending is not None and unsafe[1] > pending[0] - plan_start + CERT_STEP:
                    loop.judged_lo, loop.judged_hi = lo, hi  # the pending plan takes over in time
                    unsafe = None
                elif (
                    defer > 0.0
                    and replan_in_flight
                    and np.isfinite(unsafe[1])  # the baseline promises no manoeuvre: no deferring
                    and unsafe[1] - t_rel > defer + CERT_STEP
                ):
                    # The plan stays certified until its first failing manoeuvre: keep following
                    # it and replan `defer` before then (sooner if later evidence brings that
                    # manoeuvre closer), once, with all the camera sees meanwhile. The judged
                    # boxes stay as they were, so every later frame re-checks the plan.
                    if deferred is None:
                        event(t, "replan deferred", unsafe[0])
                    deferred = (plan_start + unsafe[1] - defer, unsafe)
                    unsafe = None
                else:
                    deferred = None
        if deferred is not None and mode == "follow" and t + 1e-9 >= deferred[0]:
            unsafe, deferred = deferred[1], None  # the deferred replan is due
        if unsafe is not None:
            t_rel = t - plan_start
            why, t_bad = unsafe
            # with latency, the current plan must stay certified until the new one starts
            in_time = latency <= 0.0 or t_bad > t_rel + latency + CERT_STEP
            replanned = None
            if replan_in_flight and replans < max_replans and in_time:
                # Line 1 of Algorithm 1 from the current (moving) state: the new plan is
                # certified from here on, its first reactive set in space the camera saw.
                replans += 1
                event(t, "replan in flight", why)
                x_from = x
                if latency > 0.0:
                    x_pred, _ = interpolate(
                        model,
                        current.times,
                        current.states,
                        current.controls,
                        np.array([t_rel + latency]),
                    )
                    x_from = x_pred[0]
                replanned = make_plan(t, x_from)
            if replanned is not None and latency > 0.0:
                pending = (t + latency, replanned, loop.start_problem)
                event(t, "plan pending", f"takes over at {t + latency:.2f} s")
                loop.judged_against_current()
            elif replanned is not None:
                current, plan_start = replanned, t
                plan_problem_snapshot = loop.start_problem
                loop.judged_against_current()
            else:
                pending = None
                mode = "brake"
                takeovers += 1
                event(t, "take-over", why, "WARN")
        if pending is not None and mode == "follow" and t + 1e-9 >= pending[0]:
            plan_start, current, plan_problem_snapshot = pending
            pending = None
            event(t, "plan takes over", f"T={current.final_time:.2f}s")
        # ---- act -----------------------------------------------------------------------------
        if mode == "follow":
            if reference[0] is not current:
                reference = (
                    current,
                    Interpolant(model, current.times, current.states, current.controls),
                )
            x_ref, u_ref = reference[1](np.array([t - plan_start]))
            u = loop.tracker.control(x, x_ref[0], u_ref[0])
        elif mode == "brake":
            u = loop.brake.control(x)
            if float(np.linalg.norm(model.velocity(x))) < STOP_SPEED:
                mode = "hold"
                event(t, "stopped", "reactive manoeuvre complete")
                last_attempt = -np.inf
                if look_around:
                    mode, headings = "scan", scan_headings(float(model.yaw(x)), hfov)
                    event(t, "look around", f"turning {np.degrees(0.5 * hfov):.0f} deg either way")
        if mode == "scan":
            while (
                headings and abs(_heading_error(headings[0], float(model.yaw(x)))) < SCAN_TOLERANCE
            ):
                headings.pop(0)
            if headings:
                u = _scan_control(model, loop.brake, x, headings[0], dt)
            else:
                mode = "hold"
        if mode == "hold":
            u = loop.brake.control(x)
            if (
                replans < max_replans
                and held_failures < 2 * STUCK_RETRIES
                and t - last_attempt >= REPLAN_RETRY
            ):
                last_attempt = t
                replans += 1
                new_plan = make_plan(t, x)
                if new_plan is not None:
                    current, plan_start, mode = new_plan, t, "follow"
                    held_failures = 0
                    deferred = None
                    plan_problem_snapshot = loop.start_problem
                    loop.judged_against_current()
                else:
                    held_failures += 1
                    if held_failures == 2 * STUCK_RETRIES:
                        event(
                            t,
                            "holding",
                            f"{held_failures} replans at rest failed: no more replans",
                            "WARN",
                        )
                    elif replans < max_replans and (look_around or held_failures == STUCK_RETRIES):
                        mode, headings = "scan", scan_headings(float(model.yaw(x)), hfov)
                        if not look_around:
                            event(
                                t,
                                "look around",
                                f"{held_failures} replans at rest failed: turning"
                                f" {np.degrees(0.5 * hfov):.0f} deg either way for new views",
                            )
        # ---- integrate and check against the truth ---------------------------------------------
        p_prev = np.asarray(model.position(x), float).ravel()
        x = np.asarray(model.step(x, u, dt), dtype=float)
        t += dt
        p_new = np.asarray(model.position(x), float).ravel()
        T_log.append(t)
        X_log.append(x.copy())
        if loop.collision.swept_collides(p_prev, p_new, r, clearance0=clear):
            collided, collision_time = True, t
            # The colliding step counts: its deepest sampled point (<= 0: the capsule touched).
            along = p_prev + np.linspace(0.0, 1.0, CONTACT_SAMPLES)[:, None] * (p_new - p_prev)
            min_clear = min(min_clear, 0.0, float(loop.collision.clearances(along, r).min()))
            collision_names = loop.collision.contact_obstacles(p_prev, p_new, r)
            event(t, "collision", ", ".join(collision_names), "ERROR")
            break
        clear = float(loop.collision.clearance(p_new, r))
        min_clear = min(min_clear, clear)
        speed = float(np.linalg.norm(model.velocity(x)))
        if rec is not None and len(T_log) % 5 == 0:
            rec.log_state(t, p_new, np.asarray(model.velocity(x), float).ravel(), speed, clear)
        if np.linalg.norm(p_new - goal) <= scenario.goal.tolerance and speed <= ARRIVAL_SPEED:
            reached, time_to_goal = True, t
            event(t, "goal reached", f"{t:.2f} s")
            break
    else:
        event(t, "time limit", f"{time_limit:.1f} s without reaching the goal", "WARN")

    states = np.array(X_log)
    positions = np.asarray(model.position(states), dtype=float)
    speeds = np.linalg.norm(np.asarray(model.velocity(states), dtype=float), axis=1)
    return SimResult(
        scenario=scenario.name,
        planner=loop.planner,
        seed=seed,
        collided=collided,
        collision_time=collision_time,
        collision_obstacles=tuple(collision_names),
        reached_goal=reached,
        time_to_goal=time_to_goal,
        min_clearance=min_clear,
        times=np.array(T_log),
        states=states,
        positions=positions,
        speeds=speeds,
        events=tuple(events),
        plans=tuple(plans),
        detection_time=detection_time,
        detection_point=detection_point,
        frames=frame_no + 1,
        takeovers=takeovers,
        replans=replans,
        solve_times=tuple(solve_times),
        wall_time=time.perf_counter() - wall0,
    )
