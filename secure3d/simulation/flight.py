"""The closed loop as an explicit state machine: the paper's Algorithm 1, line by line.

Algorithm 1 (Ivanov & Campbell) and where each line lives here::

    1  [x*(t), u*(t)] <- Solve Eq. (Obj_Highlevel)       Flight.make_plan      HOLD --PLANNED--> FOLLOW
    2  while O_u ∩ S_s(t) = ∅:                          Flight.observe        (each camera frame)
    3      u(t) = u*(t)                                  Flight.act_follow     FOLLOW
    4  if x*(t) != safe:                                 Flight.recheck, Flight.respond
    5      while evasive manoeuvre:                      FOLLOW --UNSAFE--> BRAKE
    6          u(t) = pi(x(t), O)                        Flight.act_brake      BRAKE
    7  go to 1                                           BRAKE --STOPPED--> HOLD, Flight.act_hold

The modes (:class:`Mode`) and every change between them (:data:`TRANSITIONS`) are in one table;
:meth:`Flight.go` is the only place the mode changes. Beyond the paper, and each named where it
acts: a replan from the moving state before braking (line 4 tries line 1 first), deferred replans
and replan latency (:meth:`Flight.recheck`), looking around at rest (``SCAN``), holding after
repeated failures, backing off a known obstacle the body at rest overlaps (``RETREAT``,
:mod:`secure3d.simulation.retreat`; the at-rest behaviours are in
:mod:`secure3d.simulation.at_rest`), looking at a claim or at the goal from a point a plan flies
to (``EXPLORE``), and the tracking guard (FOLLOW --OFF_TUBE--> BRAKE,
:mod:`secure3d.simulation.guard`).

One control step (:meth:`Flight.step`) is: sense (if a frame is due) and re-check the plan,
respond to a broken plan, switch to a pending plan, choose the control by mode, integrate and check
against the truth.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from secure3d.errors import SimulationError
from secure3d.planning.result import PlanStatus
from secure3d.simulation.at_rest import AtRest
from secure3d.simulation.explore import LOOK_FROM, nearer_look
from secure3d.simulation.loop import (
    CERT_STEP,
    SCAN_TOLERANCE,
    heading_error,
    new_obstacle_voxels,
    scan_control,
    scan_headings,
)
from secure3d.simulation.modes import (
    ARRIVAL_SPEED,
    CONTACT_SAMPLES,
    FLYING,
    HEARTBEAT_SECONDS,
    MAX_EXPLORATIONS,
    REPLAN_RETRY,
    RETRY_SPEEDS,
    STOP_SPEED,
    STUCK_RETRIES,
    SURFACE_BIAS,
    TRANSITIONS,
    Followed,
    Mode,
    RunSettings,
    Trigger,
    hold_after,
    log,
    replan_refusal,
    replan_time_limit,
)
from secure3d.simulation.recheck import plan_unsafe
from secure3d.simulation.recording import Recorder
from secure3d.simulation.results import SimEvent, SimResult, flight_result, log_heartbeat

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.result import PlanResult
    from secure3d.simulation.guard import TrackingGuard
    from secure3d.simulation.loop import Loop
    from secure3d.simulation.retreat import Retreat


class Flight(AtRest):
    """One closed-loop run: the state (time, state, mode, plans, counts, logs) and the steps."""

    def __init__(
        self,
        loop: Loop,
        rec: Recorder,
        settings: RunSettings,
        guard: TrackingGuard | None = None,
    ) -> None:
        self.loop, self.rec, self.s, self.guard = loop, rec, settings, guard
        self.model = loop.model
        self.events: list[SimEvent] = []
        self.plans: list[tuple[float, PlanResult]] = []
        self.solve_times: list[float] = []
        self.plan_iterations: list[int] = []
        # per judged plan call: (rejections, certified)
        self.certify_log: list[tuple[int, bool]] = []
        self.failures = 0  # failed plan calls in a row
        self.t = 0.0
        self.x = np.asarray(loop.problem.x0, dtype=float)
        self.frame_no = 0
        self.next_frame = settings.frame_period
        self.mode = Mode.HOLD
        self.current: Followed | None = None
        self.pending: Followed | None = None  # a replan waiting out its latency (start = switch)
        # a deferred replan: (due, (why, t_bad), the plan that fails at t_bad)
        self.deferred: tuple[float, tuple[str, float], object] | None = None
        self.last_attempt = 0.0
        self.headings: list[float] = []  # look-around headings still to turn to
        self.reference: tuple = (None, None)  # (plan followed, its Interpolant) for the tracker
        self.hfov = loop.problem.frustum.hfov
        self.replans = self.takeovers = 0
        self.held_failures = 0  # failed replans in a row at rest (see STUCK_RETRIES)
        self.explorations = 0
        self.retreat: Retreat | None = None  # the retreat being flown (Mode.RETREAT)
        self.retreats = 0
        self.explore_goal: np.ndarray | None = None  # the point to look from while exploring
        self.explore_block: np.ndarray | None = None  # the claim it looks at
        self.look_from = LOOK_FROM  # how far before it along the route
        self.detection_time: float | None = None
        self.detection_point: np.ndarray | None = None
        self.collided = self.reached = False
        self.collision_time: float | None = None
        self.time_to_goal: float | None = None
        self.collision_names: tuple[str, ...] = ()
        clear = loop.collision.clearance(self.model.position(self.x), self.model.body_radius)
        self.clear = self.min_clear = float(clear)
        self.T_log: list[float] = [self.t]
        self.X_log: list[np.ndarray] = [self.x.copy()]
        self.beat = time.perf_counter()

    # ---- the machine ---------------------------------------------------------------------------

    def go(self, trigger: Trigger) -> Mode:
        """Change the mode along :data:`TRANSITIONS` (the only place the mode changes)."""
        nxt = TRANSITIONS.get((self.mode, trigger))
        if nxt is None:
            raise SimulationError(
                f"closed loop: no transition from {self.mode.name} on {trigger.name}"
            )
        self.mode = nxt
        return nxt

    def event(self, kind: str, detail: str = "", level: str = "INFO") -> None:
        self.events.append(SimEvent(self.t, kind, detail))
        log.debug("%s t=%.2f s %s: %s %s", self.loop.scenario.name, self.t, level, kind, detail)
        self.rec.log_event(self.t, f"{kind}: {detail}", level)

    def run(self) -> SimResult:
        """Take off (first frame, line 1), then step until the goal, a collision or the time limit."""
        self.loop.log_world(self.rec)
        self.sense()
        self.start_following(self.make_plan(self.x), Trigger.PLANNED)
        for _ in range(int(np.ceil(self.s.time_limit / self.s.dt))):
            if self.step():
                break
        else:
            limit = self.s.time_limit
            self.event("time limit", f"{limit:.1f} s without reaching the goal", "WARN")
        return self.result()

    def step(self) -> bool:
        """One control step; True when the run is over (goal or collision)."""
        self.heartbeat()
        unsafe = self.observe()  # lines 2 and 4: sense, re-check the plan
        if unsafe is not None:
            self.respond(unsafe)
        self.switch_to_pending()
        u = self.disturbed(self.act())
        if (off := self.guard_check(u)) is not None:
            self.take_over(off[0], Trigger.OFF_TUBE)
            u = self.disturbed(self.act())  # brake from this very state
        return self.integrate(u)

    def disturbed(self, u: np.ndarray) -> np.ndarray:
        """The ``disturbance`` seam of :func:`simulate`: a gust moves the state, a tracker or
        actuator fault changes the control, before the guard and the integration see them."""
        if self.s.disturbance is None:
            return u
        x, u = self.s.disturbance(self.t, self.x.copy(), np.array(u, dtype=float))
        self.x = np.asarray(x, dtype=float)
        return np.asarray(u, dtype=float)

    # ---- sense and re-check (lines 2 and 4) ---------------------------------------------------

    def sense(self) -> tuple[np.ndarray, set[str]]:
        """Capture a frame, insert it, return (centres of the obstacle voxels it revealed outside
        the judged boxes, hidden obstacles seen)."""
        loop = self.loop
        R, o = self.model.camera_pose(self.x)
        R, o = np.asarray(R, float), np.asarray(o, float).ravel()
        frame = loop.camera.render(R, o)
        cam = loop.camera
        # Insert hits a hair (0.1 mm) in front of the surface: a wall lying exactly on a voxel
        # boundary then marks the voxel in front of it (which its claim covers) instead of flipping
        # between the two voxels with float rounding and carving the claim into fragments.
        stats = loop.insert_frame(
            frame.depth - SURFACE_BIAS, (cam.fx, cam.fy, cam.cx, cam.cy), R, o
        )
        if self.guard is not None:
            self.guard.add_view(R, o)
        new = new_obstacle_voxels(loop, stats.occupied_codes)
        self.loop.log_frame(self.rec, self.t, self.frame_no, R, o, frame.depth, self.s)
        return new, set(frame.hit_names()) & loop.hidden

    def observe(self) -> tuple[str, float] | None:
        """Sense if a frame is due and judge the plan being followed: (why, plan time of its first
        failing manoeuvre) when it must be replaced now, else None."""
        unsafe = None
        if self.t + 1e-9 >= self.next_frame:
            self.frame_no += 1
            self.next_frame += self.s.frame_period
            new, hidden_seen = self.sense()
            if hidden_seen and self.detection_time is None:
                self.detection_time = self.t
                self.detection_point = np.asarray(self.model.position(self.x), float).copy()
                self.event("hidden obstacle seen", ", ".join(sorted(hidden_seen)), "WARN")
            if len(new) and self.mode in FLYING and self.current is not None:
                unsafe = self.recheck(new)
        if self.deferred is not None and self.mode in FLYING and self.t + 1e-9 >= self.deferred[0]:
            unsafe, self.deferred = self.deferred[1], None  # the deferred replan is due
        return unsafe

    def guard_check(self, u: np.ndarray) -> tuple[str, float] | None:
        """The tracking guard (beyond the paper): will the state, one check interval ahead under
        the control ``u`` about to be applied, still be in the certified tube?"""
        if self.guard is None or self.mode not in FLYING or self.current is None:
            return None
        return self.guard.check(self.t, self.x, u, self.current, self.reference_state()[0])

    def recheck(self, new: np.ndarray) -> tuple[str, float] | None:
        """Re-certify the followed (and any pending) plan after a frame revealed the voxels ``new``:
        first against the judged boxes plus those voxels (a superset of the known obstacles), and
        only if that fails against the whole map merged afresh; then defer when allowed."""
        loop, cur, pending = self.loop, self.current, self.pending
        t_rel = self.t - cur.start
        lo, hi = loop.judged_plus(new)
        # the plan of a deferred replan fails at until: only an earlier failure is news
        held = self.deferred[1] if self.deferred and self.deferred[2] is cur.plan else None
        until = held[1] if held else np.inf
        unsafe = plan_unsafe(loop, cur.plan, cur.problem, t_rel, lo, hi, until)
        broken = None
        if pending is not None:
            broken = plan_unsafe(loop, pending.plan, pending.problem, 0.0, lo, hi)
        if unsafe is not None or broken is not None:
            loop.refresh_obstacles()
            lo, hi = loop.problem.boxes_lo, loop.problem.boxes_hi
            unsafe = plan_unsafe(loop, cur.plan, cur.problem, t_rel, lo, hi, until)
            if pending is not None:
                broken = plan_unsafe(loop, pending.plan, pending.problem, 0.0, lo, hi)
        unsafe = unsafe or held  # a held plan is still taken to fail where it did
        if broken is not None:
            self.event("pending plan dropped", broken[0], "WARN")
            self.pending = None
            unsafe = unsafe or broken
        return self.defer_or_replan(unsafe, lo, hi, t_rel)

    def defer_or_replan(
        self, unsafe: tuple[str, float] | None, lo: np.ndarray, hi: np.ndarray, t_rel: float
    ) -> tuple[str, float] | None:
        """What a re-check's verdict means now: the plan passed (judged boxes move on), a pending
        plan takes over in time, the replan is deferred (``replan_defer``), or replan now."""
        loop, defer = self.loop, self.s.replan_defer
        if unsafe is None:
            loop.judged_lo, loop.judged_hi = lo, hi
            self.deferred = None
        elif (
            self.pending is not None
            and unsafe[1] > self.pending.start - self.current.start + CERT_STEP
        ):
            loop.judged_lo, loop.judged_hi = lo, hi  # the pending plan takes over in time
            unsafe = None
        elif (
            defer > 0.0
            and self.s.replan_in_flight
            and np.isfinite(unsafe[1])  # the baseline promises no manoeuvre: no deferring
            and unsafe[1] - t_rel > defer + CERT_STEP
        ):
            # The plan stays certified until its first failing manoeuvre: keep following it and
            # replan `defer` before then (sooner if later evidence brings that manoeuvre closer),
            # once, with all the camera sees meanwhile. The judged boxes take the new voxels now:
            # the guard and later re-checks judge against them, so they stay a superset of the
            # known obstacles (kept as they were, a quadrotor campaign flew 2 mm into them).
            loop.judged_lo, loop.judged_hi = lo, hi
            if self.deferred is None:
                self.event("replan deferred", unsafe[0])
            self.deferred = (self.current.start + unsafe[1] - defer, unsafe, self.current.plan)
            unsafe = None
        else:
            self.deferred = None
        return unsafe

    # ---- respond (lines 4-5: replan from the moving state, else take over) ----------------------

    def respond(self, unsafe: tuple[str, float]) -> None:
        """The plan broke at plan time ``unsafe[1]``: replan in flight if allowed and in time
        (line 1 from the moving state), else brake (the take-over, line 5)."""
        from secure3d.planning.trajectory import interpolate

        s, cur = self.s, self.current
        t_rel = self.t - cur.start
        why, t_bad = unsafe
        # with latency, the current plan must stay certified until the new one starts
        in_time = s.replan_latency <= 0.0 or t_bad > t_rel + s.replan_latency + CERT_STEP
        replanned = None
        if s.replan_in_flight and self.replans < s.max_replans and in_time:
            # Line 1 of Algorithm 1 from the current (moving) state: the new plan is certified
            # from here on, its first reactive set in space the camera saw.
            self.replans += 1
            self.event("replan in flight", why)
            x_from = self.x
            if s.replan_latency > 0.0:
                p = cur.plan
                t_pred = np.array([t_rel + s.replan_latency])
                x_from = interpolate(self.model, p.times, p.states, p.controls, t_pred)[0][0]
            replanned = self.make_plan(x_from, goal=self.aim())
        if replanned is not None and s.replan_latency > 0.0:
            switch = self.t + s.replan_latency
            self.pending = Followed(replanned, switch, self.loop.start_problem)
            self.event("plan pending", f"takes over at {switch:.2f} s")
            self.loop.judged_against_current()
        elif replanned is not None:
            self.current = Followed(replanned, self.t, self.loop.start_problem)
            self.loop.judged_against_current()
        else:
            self.take_over(why, Trigger.UNSAFE)

    def take_over(self, why: str, trigger: Trigger) -> None:
        """Line 5: hand over to the reactive (braking) controller, now."""
        self.pending = None
        self.go(trigger)
        self.takeovers += 1
        self.event("take-over", why, "WARN")

    def switch_to_pending(self) -> None:
        if self.pending is not None and self.mode in FLYING and self.t + 1e-9 >= self.pending.start:
            self.current, self.pending = self.pending, None
            self.event("plan takes over", f"T={self.current.plan.final_time:.2f}s")

    # ---- line 1: plan ---------------------------------------------------------------------------

    def aim(self) -> np.ndarray | None:
        """Where plans go now: the point to look from while exploring, else None (the goal)."""
        return self.explore_goal if self.mode is Mode.EXPLORE else None

    def make_plan(self, x: np.ndarray, goal: np.ndarray | None = None) -> PlanResult | None:
        """Plan from state ``x`` now (line 1) to the goal (or to ``goal``): the take-off plan from
        the start region observed before take-off (the paper's premise), a replan from the box the
        camera has observed around the robot. None (and an event) if no certified plan was found."""
        from secure3d.planning.solve import plan_problem

        loop = self.loop
        speed = RETRY_SPEEDS[self.failures % len(RETRY_SPEEDS)] if self.failures else None
        # a replan at rest has failed: the next at rest with the scenario's own, finer nodes
        nodes = loop.rest_nodes if self.held_failures else None
        replan = self.t != 0.0  # not the take-off plan, which has no limit
        problem = loop.plan_problem_from(x, replan, speed=speed, goal=goal, nodes=nodes)
        loop.start_problem = problem
        t0 = time.perf_counter()
        # a replan the robot would fly: not too long a detour (round the planner's route, known
        # once the call has its first guess), nor slower than braking
        p0, vmax = np.asarray(self.model.position(x), float).ravel(), self.model.limits.max_speed
        slow = self.braking_instead(x) if replan else None

        def limit(route: float) -> float:
            return replan_time_limit(p0, problem.goal, vmax, slow, route) if replan else np.inf

        result = plan_problem(problem, loop.planner, cache=loop.cache, route_time_limit=limit)
        self.solve_times.append(time.perf_counter() - t0)
        self.plan_iterations.append(int(result.iterations))
        self.log_certificates(result)
        why = None  # TOO_SLOW: the planner stopped at a plan these rules refuse
        if replan and (result.ok or result.status is PlanStatus.TOO_SLOW):
            positions, route = self.model.position(result.states), result.route_length
            why = replan_refusal(positions, result.final_time, p0, problem.goal, vmax, slow, route)
        if not result.ok or why is not None:
            self.failures += 1
            what = why or f"{result.status.value}: {result.message}"
            self.event("plan failed", what, "WARN")
            return None
        self.failures = 0
        self.plans.append((self.t, result))
        self.event("plan", f"T={result.final_time:.2f}s solve={1e3 * self.solve_times[-1]:.0f}ms")
        self.rec.log_plan(self.t, result, label=loop.planner)
        self.rec.log_scalar(self.t, "solve_time_ms", 1e3 * self.solve_times[-1])
        return result

    def braking_instead(self, x: np.ndarray) -> tuple[float, float] | None:
        """(braking time, time left on the current plan) when a replan from state ``x`` must
        beat braking and planning from rest (moving, on the way to the goal), else None."""
        cur, speed = self.current, float(np.linalg.norm(self.model.velocity(x)))
        if cur is None or self.aim() is not None or speed < STOP_SPEED:
            return None
        return self.loop.stop_time(x), cur.plan.final_time - (self.t - cur.start)

    def log_certificates(self, result: PlanResult) -> None:
        """Count the certificate's verdicts on this plan call (issue 16's first-try rate) and say
        what it rejected."""
        if result.certificate is None:
            return
        self.certify_log.append((len(result.rejections), bool(result.certificate.ok)))
        note = result.rejection_note()
        if note is not None:
            self.event("certificate", note)

    def start_following(self, plan: PlanResult | None, trigger: Trigger) -> None:
        """HOLD -> FOLLOW on a new plan (line 1 succeeded)."""
        if plan is None:
            return
        self.current = Followed(plan, self.t, self.loop.start_problem)
        self.loop.judged_against_current()
        self.go(trigger)

    # ---- act: the control of each mode ------------------------------------------------------------

    def act(self) -> np.ndarray:
        """The control for this step, by mode (a mode that ends hands the step on to the next)."""
        return {
            Mode.FOLLOW: self.act_follow,
            Mode.BRAKE: self.act_brake,
            Mode.SCAN: self.act_scan,
            Mode.HOLD: self.act_hold,
            Mode.EXPLORE: self.act_explore,
            Mode.RETREAT: self.act_retreat,
        }[self.mode]()

    def reference_state(self) -> tuple[np.ndarray, np.ndarray]:
        """The followed plan's state and control now; past its end, a hold (:func:`hold_after`)."""
        from secure3d.planning.trajectory import Interpolant

        p = self.current.plan
        if self.t - self.current.start >= p.times[-1]:
            return hold_after(self.model, p)
        if self.reference[0] is not p:
            self.reference = (p, Interpolant(self.model, p.times, p.states, p.controls))
        return self.reference[1].at(self.t - self.current.start)  # the tracker's, then the guard's

    def act_follow(self) -> np.ndarray:
        """Line 3: track the plan."""
        x_ref, u_ref = self.reference_state()
        return self.loop.tracker.control(self.x, x_ref, u_ref)

    def act_brake(self) -> np.ndarray:
        """Lines 5-6: the reactive manoeuvre until at rest, then HOLD (or SCAN to look around)."""
        u = self.loop.brake.control(self.x)
        if float(np.linalg.norm(self.model.velocity(self.x))) >= STOP_SPEED:
            return u
        self.event("stopped", "reactive manoeuvre complete")
        self.last_attempt = -np.inf
        away = self.face_away()
        if not self.s.look_around and away is None:
            self.go(Trigger.STOPPED)
            return self.act_hold()
        self.go(Trigger.STOPPED_LOOK)
        self.headings = [] if away is None else [away]  # look around first, then face away
        if self.s.look_around:
            self.headings[:0] = scan_headings(float(self.model.yaw(self.x)), self.hfov)
            self.event("look around", f"turning {np.degrees(0.5 * self.hfov):.0f} deg either way")
        return self.act_scan(u)

    def act_scan(self, u: np.ndarray | None = None) -> np.ndarray:
        """Turn through the look-around headings at rest, then HOLD."""
        yaw = float(self.model.yaw(self.x))
        while self.headings and abs(heading_error(self.headings[0], yaw)) < SCAN_TOLERANCE:
            self.headings.pop(0)
        if self.headings:
            return scan_control(self.model, self.loop.brake, self.x, self.headings[0], self.s.dt)
        self.go(Trigger.LOOKED)
        return self.act_hold()

    def act_hold(self) -> np.ndarray:
        """Line 7, "go to 1": at rest, replan every REPLAN_RETRY s; look around once after
        STUCK_RETRIES failures in a row, stop trying after twice that many."""
        s = self.s
        u = self.loop.brake.control(self.x)
        due = self.t - self.last_attempt >= REPLAN_RETRY
        if self.replans >= s.max_replans or self.held_failures >= 2 * STUCK_RETRIES or not due:
            return u
        if self.start_retreat():  # the planner refuses a start overlapping a known obstacle
            return self.act_retreat()
        self.last_attempt = self.t
        self.replans += 1
        # near the goal, its ball's near side first: arriving anywhere inside counts, it is nearer,
        # and it lies in what the robot observed where the goal point may not
        plan = self.plan_to_goal_edge()
        if plan is None:
            plan = self.make_plan(self.x)
        if plan is not None:
            self.start_following(plan, Trigger.PLANNED)
            self.held_failures = 0
            self.deferred = None
            return u
        if self.explore():
            return u
        self.held_failures += 1
        if self.held_failures == 2 * STUCK_RETRIES:
            self.event(
                "holding", f"{self.held_failures} replans at rest failed: no more replans", "WARN"
            )
        elif self.replans < s.max_replans and (
            s.look_around or self.held_failures == STUCK_RETRIES
        ):
            self.go(Trigger.STUCK)
            self.headings = scan_headings(float(self.model.yaw(self.x)), self.hfov)
            if not s.look_around:
                self.event(
                    "look around",
                    f"{self.held_failures} replans at rest failed: turning"
                    f" {np.degrees(0.5 * self.hfov):.0f} deg either way for new views",
                )
        return u

    def explore(self) -> bool:
        """At rest, the replan failed: if the map shows no route because of a claim the camera has
        not checked, or no view has covered the goal's surroundings (:meth:`goal_view`), plan to a
        point to look at it from and fly there (HOLD -> EXPLORE)."""
        if not self.s.explore or self.explorations >= MAX_EXPLORATIONS:
            return False
        found, self.look_from = nearer_look(
            self.loop.start_problem, self.loop.belief, self.explore_block, self.look_from
        )
        what = "the map shows no route: looking at the claim at {} from {}"
        if found is None:
            found = self.goal_view()
            what = "no view covered the goal's surroundings: looking at {} from {}"
        if found is None:
            return False
        view, block = found
        self.explorations += 1
        at, frm = np.round(block, 2).tolist(), np.round(view, 2).tolist()
        self.event("explore", what.format(at, frm), "WARN")
        plan = self.make_plan(self.x, goal=view)
        if plan is None:
            return False
        self.explore_goal, self.explore_block = view, block
        self.start_following(plan, Trigger.DENIED)
        self.held_failures = 0
        self.deferred = None
        return True

    def act_explore(self) -> np.ndarray:
        """Fly to the point to look from; once there (the plan ends at rest), turn to face the
        claim (EXPLORE -> SCAN), then replan (SCAN -> HOLD)."""
        if self.t - self.current.start < self.current.plan.final_time - 1e-9:
            return self.act_follow()
        p = np.asarray(self.model.position(self.x), dtype=float).ravel()
        towards = self.explore_block - p
        self.event(
            "looking",
            f"at the point to look from: turning towards {np.round(self.explore_block, 2).tolist()}",
        )
        self.go(Trigger.ARRIVED)
        self.headings = [float(np.arctan2(towards[1], towards[0]))]
        self.explore_goal = None
        self.last_attempt = -np.inf
        self.held_failures = 0
        return self.act_scan()

    # ---- integrate and check against the truth --------------------------------------------------

    def integrate(self, u: np.ndarray) -> bool:
        """Step the vehicle; check the swept body against the true world and the goal."""
        model, loop, r = self.model, self.loop, self.model.body_radius
        p_prev = np.asarray(model.position(self.x), float).ravel()
        self.x = np.asarray(model.step(self.x, u, self.s.dt), dtype=float)
        self.t += self.s.dt
        p_new = np.asarray(model.position(self.x), float).ravel()
        self.T_log.append(self.t)
        self.X_log.append(self.x.copy())
        if loop.collision.swept_collides(p_prev, p_new, r, clearance0=self.clear):
            self.collided, self.collision_time = True, self.t
            # The colliding step counts: its deepest sampled point (<= 0: the capsule touched).
            along = p_prev + np.linspace(0.0, 1.0, CONTACT_SAMPLES)[:, None] * (p_new - p_prev)
            deepest = float(loop.collision.clearances(along, r).min())
            self.min_clear = min(self.min_clear, 0.0, deepest)
            self.collision_names = loop.collision.contact_obstacles(p_prev, p_new, r)
            self.event("collision", ", ".join(self.collision_names), "ERROR")
            return True
        self.clear = float(loop.collision.clearance(p_new, r))
        self.min_clear = min(self.min_clear, self.clear)
        speed = float(np.linalg.norm(model.velocity(self.x)))
        if len(self.T_log) % 5 == 0:
            v = np.asarray(model.velocity(self.x), float).ravel()
            self.rec.log_state(self.t, p_new, v, speed, self.clear)
        goal = self.loop.scenario.goal
        if np.linalg.norm(p_new - self.s.goal) <= goal.tolerance and speed <= ARRIVAL_SPEED:
            self.reached, self.time_to_goal = True, self.t
            self.event("goal reached", f"{self.t:.2f} s")
            return True
        return False

    # ---- logging and the result -----------------------------------------------------------------

    def heartbeat(self) -> None:
        if time.perf_counter() - self.beat >= HEARTBEAT_SECONDS:
            self.beat = time.perf_counter()
            log_heartbeat(self.loop.scenario.name, self.t, self.s, self.beat, len(self.plans))

    def result(self) -> SimResult:
        return flight_result(self)
