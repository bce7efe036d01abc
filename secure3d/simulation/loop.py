"""The state of one closed-loop run and the pieces of it that do not depend on the mode.

:class:`Loop` holds the true world, the camera, the collision world, the belief map, the planning
problem and the compiled NLP; :func:`new_obstacle_voxels` tells what a frame revealed;
:func:`observed_box` is a replan's start region in flight; :func:`scan_headings` and
:func:`scan_control` turn a robot at rest to look around. The mode logic is in
:mod:`secure3d.simulation.flight`.
"""

from __future__ import annotations

import dataclasses
from collections import OrderedDict, deque
from typing import TYPE_CHECKING

import numpy as np

from secure3d._kernel_manifest import preload
from secure3d.errors import SimulationError
from secure3d.simulation.modes import STOP_SPEED

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.problem import PlanningProblem
    from secure3d.simulation.recheck import Recheck
    from secure3d.simulation.recording import Recorder
    from secure3d.simulation.retreat import Retreat
    from secure3d.world.spec import PlannerSpec, Scenario

#: Fraction of the model's yaw-rate limit used to look around at rest, and the yaw error (rad) at
#: which a look-around heading counts as reached.
SCAN_RATE_FRACTION = 0.8
SCAN_TOLERANCE = 0.05

#: The certificate's sampling step (s): a manoeuvre that fails at plan time t_bad leaves the robot
#: until t_bad minus this to switch to a new plan.
CERT_STEP = 0.02

#: Obstacle slots per node in closed loop (the planner's default is 8; see ``Loop``).
CLOSED_LOOP_OBSTACLE_SLOTS = 12
#: IPOPT's iteration limit per solve in closed loop, unless the scenario's ``planner.max_iter`` is
#: lower or the caller sets ``max_iter`` (``plan()`` keeps ``planner.max_iter``, 500 by default). On every scenario in maps/ each solve of a flight
#: converges in 12-90 iterations. A quadrotor replanning at 4.6 m/s towards a hidden thin obstacle
#: (campaign family ``thin``) ran 500-iteration solves that failed, 7-21 s each, before a slower
#: guess converged (plan calls of 10-41 s); the robot brakes safely when a replan fails and plans
#: from rest instead (Algorithm 1, lines 4-7).
CLOSED_LOOP_MAX_ITER = 200
#: Collocation nodes of every plan in closed loop, unless the scenario's ``planner.nodes`` is fewer
#: or the caller sets ``nodes`` (``plan()`` keeps ``planner.nodes``). The certificate judges the
#: continuous trajectory whatever K is, so fewer nodes weaken nothing; they cut the solve time
#: (about K^1.6). Every shipped scenario's flight, 40 nodes against 24, one run each: plan
#: calls 75.7 -> 34.3 s in all, 23 of 23 at the goal, 0 collisions either way
#: (``benchmarks/results/session42.md``). After a replan at rest has failed, the robot's next
#: replans at rest use the scenario's own ``planner.nodes`` (``Loop.rest_nodes``): in 400 quadrotor
#: campaign runs, 3 robots held still at 24 nodes where 40-50 reached the goal.
CLOSED_LOOP_NODES = 24
#: Frames (the latest) a replan's certificate counts as views taken before the plan: half a second
#: to a second at 15-30 Hz. The NLP plans with its start box; these let the certificate accept the first
#: manoeuvres a frame just saw although they leave that box and the braking path (a quadrotor's
#: replan in flight was refused 7e-5 m off the path; one at 3.3 m/s 4 mm beside it).
PAST_FRAMES = 16


class Loop:
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
        # the kernels earlier flights called, loaded (or compiled) now rather than in the flight
        self.kernels_preloaded = preload()
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
        # Frames update only the voxels that meet the planning domain, the world's bounds: the
        # certificate refuses a body that leaves them, so nothing outside can matter. A camera
        # sees far beyond a room without floor or ceiling: at 2 cm voxels, carving that space
        # cost most of a flight's wall time (CHANGELOG, session 27).
        bounds = scenario.world.bounds
        self.map_box = np.array([bounds.lo, bounds.hi], dtype=float)
        options, self.rest_nodes = closed_loop_options(scenario.planner, options)
        # no obstacle boxes yet: the first frame goes into the map before the first plan, which
        # merges them (:meth:`refresh_obstacles`)
        no_boxes = (np.empty((0, 3)), np.empty((0, 3)))
        self.problem = problem_from_scenario(
            scenario, belief=self.belief, obstacle_boxes=no_boxes, **options
        )
        self.model = self.problem.model
        # A frame clears space only where it would surely have hit an obstacle of the guaranteed
        # size: within the observed range, less a voxel diagonal so that every cleared voxel lies
        # wholly inside it. Farther, rays pass either side of a thin obstacle, and the start region
        # of a replan in flight (observed_box) would count its voxels as observed.
        fr = self.problem.frustum
        self.free_range = max(0.0, fr.far - float(np.sqrt(3.0)) * self.belief.resolution)
        #: the last PAST_FRAMES frames inserted (rotation, origin): a replan's certificate counts them
        #: as views earlier than the plan (``PlanningProblem.past_views``)
        self.frames: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=PAST_FRAMES)
        self.brake = BrakingController(self.model)
        self.tracker = make_tracker(self.model)
        # the planner's module-wide cache by default: runs in one process share compiled NLPs
        self.cache = cache if cache is not None else DEFAULT_CACHE
        # Compile the NLP before take-off, as a robot would (part of the set-up; see simulate). A
        # look-back assignment compiled into the structure (the default) is known only at plan
        # time: then the first plan compiles it, in flight.
        self.cache.prepare(self.problem, planner)
        self.hidden = set(scenario.hidden_obstacles)
        self.start_problem = self.problem
        self.first_problem = self.problem  # its start region was observed before take-off
        #: per plan re-certified in flight (by id, the last few): its sampled manoeuvres, the boxes
        #: it last passed against and what observed its manoeuvre points then (:func:`plan_unsafe`)
        self.rechecks: OrderedDict[int, Recheck] = OrderedDict()
        # obstacle boxes the plan being followed was last planned or certified against
        self.judged_lo: np.ndarray | None = None
        self.judged_hi: np.ndarray | None = None
        #: voxels found inside the judged boxes by earlier frames (:func:`new_obstacle_voxels`)
        self.inside_memo = InsideMemo()

    def insert_frame(
        self, depth: np.ndarray, intrinsics: tuple, R: np.ndarray, o: np.ndarray
    ) -> object:
        """Insert a z-depth frame taken from pose (``R``, ``o``) into the belief: hits out to the
        sensor's ``max_range``, free space out to :attr:`free_range` (in the camera's
        ``far_kind``). Returns the insert statistics."""
        cam = self.scenario.camera
        stats = self.belief.insert_depth_image(
            depth,
            intrinsics,
            R,
            o,
            cam.max_range,
            discretize=cam.discretize,
            far_kind=cam.far_kind,
            box=self.map_box,
            free_range=self.free_range,
        )
        # a view counts only once its frame is in the map (whatever it hit is a known obstacle)
        self.frames.append((np.asarray(R, dtype=float), np.asarray(o, dtype=float)))
        return stats

    def refresh_obstacles(self) -> None:
        lo, hi = self.belief.known_obstacle_boxes(close_gaps=self.problem.options.close_gaps)
        self.problem = dataclasses.replace(self.problem, boxes_lo=lo, boxes_hi=hi)

    def plan_problem_from(
        self,
        x: np.ndarray,
        in_flight: bool,
        speed: float | None = None,
        goal: np.ndarray | None = None,
        nodes: int | None = None,
    ) -> PlanningProblem:
        """The problem of a plan from state ``x`` (Algorithm 1, line 1) on the current obstacle
        boxes. Before take-off the start region is the one observed then (the paper's premise); in
        flight it is the box the camera has actually seen around the robot (:func:`observed_box`),
        and a moving robot's plan call fails when the first guess's solve does (no slower
        guesses). ``speed``: the guess's speed fraction after failed plans; ``goal``: another goal;
        ``nodes``: other collocation nodes."""
        self.refresh_obstacles()
        problem = self.problem
        if in_flight:
            if float(np.linalg.norm(self.model.velocity(x))) >= STOP_SPEED:
                # moving: if the first guess fails the robot brakes and plans from rest (lines
                # 4-7), sooner than slower guesses, which converged to plans 2-2.5x as long
                problem = problem.with_options(slower_guesses=False)
            p = np.asarray(self.model.position(x), dtype=float).ravel()
            first = self.first_problem
            box = observed_box(
                self.belief,
                p,
                problem.options.start_region_radius,
                assumed=(first.start_region_lo, first.start_region_hi),
            )
            views = None
            if self.frames:
                R, o = zip(*self.frames, strict=True)
                views = (np.stack(R), np.stack(o))
            region = box if box is not None else (p, p)
            problem = problem.with_start(x, region=region, past_views=views)
        if speed is not None:
            problem = problem.with_options(guess_speed_fraction=speed)
        if nodes is not None:
            problem = problem.with_options(nodes=nodes)
        if goal is not None:
            problem = dataclasses.replace(problem, goal=np.asarray(goal, dtype=float))
        return problem

    def stop_time(self, x: np.ndarray) -> float:
        """Seconds the braking manoeuvre takes from state ``x`` to below STOP_SPEED."""
        t, X = self.brake.rollout(np.asarray(x, dtype=float), dt=0.01)
        moving = np.linalg.norm(np.asarray(self.model.velocity(X), dtype=float), axis=-1)
        slow = np.flatnonzero(moving < STOP_SPEED)
        return float(t[slow[0]] if len(slow) else t[-1])

    def way_off(self, model: object, x: np.ndarray) -> float | None:
        """For a vehicle whose heading is its direction of motion, at rest in state ``x`` within
        the planner's margin of a known obstacle: the heading to turn to before replanning
        (:func:`escape_heading`); else None."""
        if not model.heading_follows_path:
            return None
        self.refresh_obstacles()
        p = np.asarray(model.position(x), dtype=float).ravel()
        lo, hi, margin = self.problem.boxes_lo, self.problem.boxes_hi, self.problem.options.margin
        return escape_heading(p, model.body_radius, lo, hi, margin, model.planar)

    def retreat_from(self, x: np.ndarray, t: float, in_margin: bool = False) -> Retreat | None:
        """At rest in state ``x`` at time ``t`` with the body overlapping a known obstacle (or,
        ``in_margin``, within the planner's margin of one): the straight retreat off it
        (:func:`~secure3d.simulation.retreat.plan_retreat`), else None."""
        from secure3d.simulation.retreat import plan_retreat

        self.refresh_obstacles()
        p, first = self.problem, self.first_problem
        return plan_retreat(
            self.model,
            x,
            t,
            (p.boxes_lo, p.boxes_hi),
            p.options.margin,
            self.belief,
            (p.bounds_lo, p.bounds_hi),
            seen=(first.start_region_lo, first.start_region_hi),
            within=p.options.margin if in_margin else 0.0,
        )

    def judged_against_current(self) -> None:
        """The plan being followed is now known safe against the current obstacle boxes."""
        self.judged_lo, self.judged_hi = self.problem.boxes_lo, self.problem.boxes_hi

    def log_world(self, rec: Recorder) -> None:
        """Record the true world and the server's claim (nothing without a recording)."""
        if not rec.recording:
            return
        from secure3d.world.attacks import server_claim

        claim = server_claim(self.scenario)
        rec.log_world(
            true_boxes=self.truth.boxes,
            true_meshes=self.truth.meshes,
            claimed_boxes=claim.boxes,
            claimed_meshes=claim.meshes,
            hidden_names=tuple(self.hidden),
            bounds=self.scenario.world.bounds,
            true_voxels=self.truth.voxel_boxes,
            true_voxel_colors=voxel_colors(self.scenario),
        )

    def log_frame(
        self,
        rec: Recorder,
        t: float,
        frame_no: int,
        R: np.ndarray,
        o: np.ndarray,
        depth: np.ndarray,
        every: object,
    ) -> None:
        """Record frame ``frame_no`` and the belief, decimated as ``every`` says
        (``frame_log_every``, ``belief_log_every``)."""
        if not rec.recording:
            return
        if frame_no % every.frame_log_every == 0:
            cam, spec = self.camera, self.scenario.camera
            rec.log_camera(t, R, o, cam.fx, cam.fy, spec.width, spec.height, depth)
        if frame_no % every.belief_log_every == 0:
            occ, trust = self.belief.known_obstacles()
            if len(occ):
                rec.log_belief(t, occ, trust, self.belief.resolution)

    def judged_plus(self, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The judged boxes plus the voxels at ``centres`` (merged into few boxes): a superset of
        the known obstacles when ``centres`` are all the known obstacle voxels found outside the
        judged boxes since they were set (see :func:`new_obstacle_voxels`). Certifying against it
        is sound (more obstacles never help a plan) and needs no re-merge of the whole map."""
        from secure3d.geometry.box_index import BoxIndex
        from secure3d.mapping.boxes import merge_cells

        res = self.belief.resolution
        klo, khi = merge_cells(np.floor(centres / res).astype(np.int64))
        # the spatial index of the judged boxes, extended by the new ones (no rebuild); problems on
        # these boxes find it by content (BoxIndex.of)
        index = BoxIndex.of(self.judged_lo, self.judged_hi).extended(klo * res, (khi + 1) * res)
        return index.lo, index.hi


def closed_loop_options(spec: PlannerSpec, options: dict) -> tuple[dict, int | None]:
    """The planner options of a closed-loop run: the caller's ``options`` with the closed loop's
    defaults for what they leave out (``spec``: the scenario's planner section), and the nodes of a
    replan at rest after one there failed (None: the same as every other plan)."""
    # The look-back assignment is compiled into each NLP's structure (the planner's default):
    # a new assignment costs a ~0.1 s build, and the NLP's KKT factorisation stays sparse.
    # As a parameter (one NLP for every assignment) the dense selection rows cost 3-5x the
    # time per IPOPT iteration (benchmarks/results/nlp_iteration.md).
    # Sensed surfaces reach the planner as many small boxes: with 8 slots per node most
    # replans in flight re-selected slots and re-solved 3 times (8 hidden-obstacle variants:
    # 0.44x real time with 8 slots, 0.52x with 10, 0.54x with 12, 0.26x with 16).
    options = dict(options)
    options.setdefault("obstacle_slots", CLOSED_LOOP_OBSTACLE_SLOTS)
    options.setdefault("max_iter", min(spec.max_iter, CLOSED_LOOP_MAX_ITER))
    chosen = "nodes" in options
    options.setdefault("nodes", min(spec.nodes, CLOSED_LOOP_NODES))
    rest_nodes = None if chosen or spec.nodes <= options["nodes"] else spec.nodes
    return options, rest_nodes


def voxel_colors(scenario: Scenario) -> np.ndarray | None:
    """r, g, b of ``world.octomap``'s voxels for a colour tree, else None."""
    from secure3d.world.attacks import octomap_voxel_colors

    w = scenario.world
    return None if w.octomap is None else octomap_voxel_colors(w.octomap, "world.octomap")


class InsideMemo:
    """Voxels already found inside the judged boxes, for :func:`new_obstacle_voxels`.

    A wall the camera keeps in view is hit frame after frame, and its voxels lie inside the judged
    boxes every time. Whether a voxel's centre lies inside boxes depends only on the voxel and the
    boxes, and the judged boxes mostly grow (:meth:`Loop.judged_plus` appends to them): a voxel
    inside them stays inside. So the codes found inside are kept while the judged boxes start with
    the boxes they were found in, and only the other voxels are tested."""

    def __init__(self) -> None:
        self.lo = np.empty((0, 3))
        self.hi = np.empty((0, 3))
        #: (k,) int64, ascending: Morton codes of voxels whose centres lie inside (lo, hi)
        self.codes = np.empty(0, dtype=np.int64)

    def known_inside(self, lo: np.ndarray, hi: np.ndarray, codes: np.ndarray) -> np.ndarray:
        """(n,) bool: which ``codes`` (n,) were found inside boxes that (``lo``, ``hi``) (m, 3)
        still hold; forgets them when (lo, hi) no longer begins with those boxes. Raises
        :class:`SimulationError` for boxes that are not two (m, 3) arrays or codes that are not
        one row of integers."""
        _check_memo_input(codes, lo, hi)
        n = len(self.lo)
        grown = len(lo) >= n and (
            (lo is self.lo and hi is self.hi)
            or (np.array_equal(lo[:n], self.lo) and np.array_equal(hi[:n], self.hi))
        )
        if not grown:
            self.codes = np.empty(0, dtype=np.int64)
        # kept as given only if read-only (a BoxIndex's own arrays), else copied: the comparison
        # above must see the boxes the codes were found in
        self.lo, self.hi = (a if not a.flags.writeable else a.copy() for a in (lo, hi))
        if not len(self.codes):
            return np.zeros(len(codes), dtype=bool)
        at = np.minimum(np.searchsorted(self.codes, codes), len(self.codes) - 1)
        return self.codes[at] == codes

    def add(self, codes: np.ndarray) -> None:
        """Remember ``codes`` (k,), none of them known yet, as inside the boxes last given to
        :meth:`known_inside`."""
        _check_memo_input(codes)
        if len(codes):
            new = np.sort(codes)  # merged into the ascending codes in O(k log k + n), not a re-sort
            self.codes = np.insert(self.codes, np.searchsorted(self.codes, new), new)


def _check_memo_input(codes: object, lo: object = None, hi: object = None) -> None:
    """Raise :class:`SimulationError` naming a malformed argument of :class:`InsideMemo`."""
    if not (isinstance(codes, np.ndarray) and codes.ndim == 1 and codes.dtype.kind in "iu"):
        what = f"shape {np.shape(codes)}" if isinstance(codes, np.ndarray) else type(codes).__name__
        raise SimulationError(f"InsideMemo: codes must be a 1-D integer array, got {what}")
    for name, a in (("lo", lo), ("hi", hi)):
        if a is not None and not (isinstance(a, np.ndarray) and a.ndim == 2 and a.shape[1] == 3):
            raise SimulationError(f"InsideMemo: {name} must be an (m, 3) array, got {np.shape(a)}")
    if lo is not None and np.shape(lo) != np.shape(hi):
        raise SimulationError(f"InsideMemo: lo {np.shape(lo)} and hi {np.shape(hi)} differ")


def new_obstacle_voxels(loop: Loop, occupied_codes: np.ndarray) -> np.ndarray:
    """Centres ``(n, 3)`` of the known obstacle voxels among those a frame (already inserted)
    updated as occupied (``occupied_codes``, Morton codes) that the boxes the current plan was last
    judged against do not cover.

    Only a hit can make a voxel a known obstacle (misses only ever free voxels, which shrinks the
    obstacle set and so cannot break a plan: fewer obstacles never block a view or a manoeuvre). So
    if every known obstacle voxel this frame hit is covered, the obstacle set is still inside the
    judged boxes and the plan stays certified; otherwise the frame revealed something new. Voxels
    that merely flicker (hit, then carved by grazing rays) are not news unless they end up occupied.
    Voxels an earlier frame found inside the judged boxes are not tested again
    (:class:`InsideMemo`).
    """
    if loop.judged_lo is None or not len(occupied_codes):
        return np.empty((0, 3))
    from secure3d.geometry.box_index import BoxIndex
    from secure3d.mapping.keys import codes_to_coords

    known = occupied_codes[loop.belief.is_known_obstacle_sensed(occupied_codes)]
    if not len(known):
        return np.empty((0, 3))
    memo = loop.inside_memo
    known = known[~memo.known_inside(loop.judged_lo, loop.judged_hi, known)]
    centres = codes_to_coords(known, loop.belief.resolution)
    if not len(centres):
        return centres
    inside = BoxIndex.of(loop.judged_lo, loop.judged_hi).inside_any(centres)
    memo.add(known[inside])
    return centres[~inside]


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
    unobserved. Sound only if the frames cleared space no farther than the camera's observed range
    (``free_range`` of :meth:`Loop.insert_frame`): beyond it, rays pass either side of a thin
    obstacle and clear its voxels.
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


def heading_error(target: float, yaw: float) -> float:
    """``target - yaw`` wrapped to (-pi, pi] (rad)."""
    return float(np.angle(np.exp(1j * (target - yaw))))


def scan_control(
    model: object, brake: object, x: np.ndarray, target: float, dt: float
) -> np.ndarray:
    """Hold still (the braking law) while turning the heading towards ``target``."""
    u = np.array(brake.control(x), dtype=float)
    err = heading_error(target, float(model.yaw(x)))
    model.turn_in_place_control(u, x, err, SCAN_RATE_FRACTION, dt)
    return u


def escape_heading(
    position: np.ndarray,
    radius: float,
    boxes_lo: np.ndarray,
    boxes_hi: np.ndarray,
    margin: float,
    planar: bool,
) -> float | None:
    """The heading (rad) pointing away from the known obstacles the body at ``position`` (3,)
    rests within ``margin`` of, or None if it rests farther from all of them (or they surround it).

    Boxes are ``boxes_lo``, ``boxes_hi`` (n, 3). The direction is the sum of the unit vectors from
    the nearest point of each such box to the body's centre (in the plane for a ``planar`` body),
    the way out of a corner as well as off a wall.

    A robot whose heading is its direction of motion (a differential drive) that brakes to rest
    with its side against a wall can only leave it by turning first. A replan from there is a
    min-time plan that sets off along the wall at zero margin, and a few millimetres of tracking
    error hand it back to the brakes, each stop a little closer, until the start touches the wall
    (``planar_dead_end``: 1.6 mm, then 0.01 mm, then inside). Turning in place on the spot is the
    look-around's motion: the body does not move."""
    p = np.asarray(position, dtype=float).ravel()
    lo = np.asarray(boxes_lo, dtype=float).reshape(-1, 3)
    hi = np.asarray(boxes_hi, dtype=float).reshape(-1, 3)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise SimulationError(
            f"escape_heading: position must be 3 finite numbers, got {position!r}"
        )
    for name, v in (("radius", radius), ("margin", margin)):
        if not np.isfinite(v) or v < 0:
            raise SimulationError(f"escape_heading: {name} must be finite and >= 0, got {v!r}")
    if lo.shape != hi.shape:
        raise SimulationError(f"escape_heading: boxes_lo {lo.shape} and boxes_hi {hi.shape} differ")
    from secure3d.simulation.retreat import away_from

    out = away_from(p, radius + margin, lo, hi, planar)
    if out is None or np.linalg.norm(out[:2]) < 1e-6:
        return None
    return float(np.arctan2(out[1], out[0]))
