"""The planning problem: *what* is solved (the paper's problem TightProb), kept apart from *how* it is
transcribed (:mod:`secure3d.planning.collocation`) and from the solver (:mod:`.solve`).

A :class:`PlanningProblem` is built from a :class:`~secure3d.world.spec.Scenario` and the robot's
belief map (server claim plus sensor evidence, see :mod:`secure3d.mapping`): the planner only ever
sees *known* obstacles (eq. NLP: d(S_r(x_i), Ĉ_obst) > 0), never the true world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING, Literal

import numpy as np

from secure3d.errors import ConfigError
from secure3d.geometry.box_index import BoxIndex
from secure3d.geometry.polytope import polyline_distance
from secure3d.mapping.observability import observed_frustum
from secure3d.validation import is_int_in, is_real

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.dynamics.base import VehicleModel
    from secure3d.geometry.frustum import PinholeFrustum
    from secure3d.mapping.occupancy import OccupancyMap
    from secure3d.reactive.reactive_set import ReactiveSetFamily
    from secure3d.world.spec import Scenario

PlannerKind = Literal["secure", "baseline"]


def _check_positive(name: str, value: float, *, allow_zero: bool = False) -> None:
    if not is_real(value) or not math.isfinite(value):
        raise ConfigError(f"planner option {name}: expected a finite number, got {value!r}")
    if value < 0 or (value == 0 and not allow_zero):
        raise ConfigError(
            f"planner option {name}: must be {'>= 0' if allow_zero else '> 0'}, got {value!r}"
        )


def _check_choice(name: str, value: object, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ConfigError(
            f"planner option {name}: {' or '.join(map(repr, choices))}, got {value!r}"
        )


#: Farthest look-back of the adaptive rule with fatrop (its register depth), unless set.
FATROP_MAX_SPAN = 6


class Planner(StrEnum):
    """Which problem is solved: the paper's secure NLP (visibility of every reactive set, eq. NLP)
    or the baseline (the same minimum-time problem without the visibility rows). A ``StrEnum``:
    ``"secure"`` and ``Planner.SECURE`` compare equal, so callers may pass either."""

    SECURE = "secure"
    BASELINE = "baseline"


class Solver(StrEnum):
    """The NLP solver (``PlannerOptions.solver``); each has its transcription
    (:data:`secure3d.planning.nlp_cache.TRANSCRIPTIONS`)."""

    IPOPT = "ipopt"
    FATROP = "fatrop"


@dataclass(frozen=True)
class PlannerOptions:
    """How the NLP is transcribed and solved.

    Attributes
    ----------
    nodes : collocation nodes K (the paper's K).
    collocation : ``"trapezoidal"`` (default) or ``"hermite_simpson"``.
    lookback : ``"fixed"`` (the paper's constant Δi, eq. NLP) or ``"adaptive"`` (node i is tied to the
        earlier node whose frustum holds its reactive set with the largest margin on the guess, and
        if that solve fails, to the latest with nearly that margin; optionally re-assigned on the
        solution, ``lookback_rounds``: the relaxation the paper leaves open).
    lookback_steps : the paper's Δi for the fixed rule.
    lookback_rounds : most re-assignments for the adaptive rule.
    lookback_max_span : farthest look-back (nodes) the adaptive rule may pick; None: any earlier
        node with IPOPT, :data:`FATROP_MAX_SPAN` with fatrop (whose shift register of camera states
        is as deep as the longest look-back).
    lookback_encoding : how the assignment reaches the compiled NLP. ``"structure"`` (the default,
        in closed loop too): each node's frustum rows read the assigned node's state directly, one
        compiled NLP per assignment (a ~0.1 s build for every new assignment). ``"parameter"``: a
        selection-matrix parameter and linear viewing-state rows, one compiled NLP for every
        assignment, but the dense selection rows cost 2-4x the time per IPOPT iteration
        (``benchmarks/results/nlp_iteration.md``).
    solver : ``"ipopt"`` (MUMPS) or ``"fatrop"``.
    margin : clearance required of every visibility and obstacle constraint (m): the ε of the
        paper's Assumption 2, which makes the discrete constraints imply the continuous ones.
    obstacle_slots : obstacles considered per node (the nearest to that node's line-of-sight hull).
    slot_pick : ``"nearest"`` (default) or, opt-in, ``"directions"``: S of the 2S nearest, first the
        nearest in each direction (:func:`~secure3d.planning.slot_screen.by_direction`; secure
        only). Fewer cold iterations, some slower plans: ``benchmarks/results/session41.md``.
    one_sided_duals : separation duals with one component per box axis, on the side of the box
        where the node's set lies (3 variables per slot instead of 6; IPOPT only). Sound: any
        dual-feasible lam gives a lower bound on the distance, a restricted one included. Measured
        (K=40, medians of 3): blind_corner cold secure solve 0.52 -> 0.29 s, baseline 0.55 -> 0.13
        s, same final time; but planar_passage_50cm's baseline fails (IPOPT step error) and in
        closed loop replans find slower plans (8 blind-corner variants: 4.5-5.2 s -> 5.6-13.9 s to
        the goal), so it is off by default.
    obstacle_radius : obstacles farther than this from a node's hull are ignored there (m).
    occlusion : require the line-of-sight hull conv({o_j} ∪ E_i) to miss known obstacles (beyond the
        paper, whose frustum sees through walls).
    interval_rows : secure IPOPT transcription only: node i+1's reactive set must also lie in node
        i's view (the frustum of node j(i) < i, with a clear sight through node i's separating
        planes) and clear of node i's obstacle slots through those planes. Both ends of the
        interval then satisfy one condition that is convex in the set's (centre, shape), so every
        ellipsoid interpolated between them does too (the support n.c + |M^T n| is convex in
        (c, M)); what is left between the nodes is the trajectory's curvature, which the margin
        covers. After a start-region node only the clearance is added. Off by default: measured
        (``benchmarks/results/certificate_rate.md``) they removed the first-try rejections of a
        3D-occlusion flight, but cost 3-50x the solve time of shipped scenarios' plans (blind_corner
        0.18 -> 1.55 s) and thin_pole's plan ran out of its budget.
    start_region_radius : half-size of the box around the start position counted as observed (m).
    effort_weight : weight of the normalised control effort added to the final time (regularises
        the bang-bang minimum-time solution; small).
    max_iter : solver iteration limit per solve; time_limit : wall-clock limit per solve (s).
    plan_budget : wall-clock budget of one plan call (s): its solves, retries, extra starts and
        certificate re-solves together. An IPOPT solve running when it is spent stops at its next
        iteration, and no further solve starts (status ``TIME_BUDGET``).
    certify : run :func:`secure3d.certify` on secure plans and report NOT_CERTIFIED on failure.
    close_gaps : voxels of morphological closing applied to the belief's obstacles before they are
        merged into boxes (:meth:`~secure3d.mapping.occupancy.OccupancyMap.known_obstacle_boxes`):
        turns sensed surface combs into solid boxes; closes openings narrower than 2 voxels.
    grid_resolution : cell size of the graph search that makes the initial guess (m).
    guess_speed_fraction : cruise speed of the initial guess, as a fraction of the speed limit.
    extra_starts : further cruise-speed fractions to start from (cold plans only); the fastest
        plan that succeeds (and, secure, certifies) is returned. Each costs a solve.
    slower_guesses : when the solve from a cold plan's first guess fails, start again from slower
        guesses (``solve.RETRY_GUESS_SPEEDS``); off, the plan call fails then. The closed loop turns
        it off for replans from a moving state, whose fallback is braking.
    verbose : print solver output.
    """

    nodes: int = 40
    collocation: Literal["trapezoidal", "hermite_simpson"] = "trapezoidal"
    lookback: Literal["adaptive", "fixed"] = "adaptive"
    lookback_steps: int = 3
    lookback_rounds: int = 1
    lookback_max_span: int | None = None
    lookback_encoding: Literal["structure", "parameter"] = "structure"
    solver: Literal["ipopt", "fatrop"] = "ipopt"
    margin: float = 0.02
    obstacle_slots: int = 8
    slot_pick: Literal["nearest", "directions"] = "nearest"
    one_sided_duals: bool = False
    obstacle_radius: float = 1.5
    occlusion: bool = True
    interval_rows: bool = False
    start_region_radius: float = 1.0
    effort_weight: float = 1e-3
    max_iter: int = 500
    time_limit: float = 60.0
    plan_budget: float = 60.0
    certify: bool = True
    close_gaps: int = 1
    grid_resolution: float = 0.2
    guess_speed_fraction: float = 0.8
    extra_starts: tuple[float, ...] = ()
    slower_guesses: bool = True
    verbose: bool = False

    @property
    def max_span(self) -> int | None:
        """The adaptive rule's farthest look-back in effect (None: unlimited)."""
        if self.lookback_max_span is not None:
            return self.lookback_max_span
        return FATROP_MAX_SPAN if self.solver == Solver.FATROP else None

    def __post_init__(self) -> None:
        if not is_int_in(self.nodes, 5, 400):
            raise ConfigError(
                f"planner option nodes: must be an integer in [5, 400], got {self.nodes!r}"
            )
        _check_choice("collocation", self.collocation, ("trapezoidal", "hermite_simpson"))
        if self.lookback_max_span is not None and not is_int_in(self.lookback_max_span, 1):
            raise ConfigError(
                "planner option lookback_max_span: must be None or an integer >= 1, got"
                f" {self.lookback_max_span!r}"
            )
        _check_choice("lookback_encoding", self.lookback_encoding, ("structure", "parameter"))
        _check_choice("lookback", self.lookback, ("adaptive", "fixed"))
        if not isinstance(self.lookback_steps, int) or not 1 <= self.lookback_steps < self.nodes:
            raise ConfigError(
                f"planner option lookback_steps: must be an integer in [1, nodes), got {self.lookback_steps!r}"
            )
        if not isinstance(self.lookback_rounds, int) or self.lookback_rounds < 1:
            raise ConfigError(
                f"planner option lookback_rounds: must be >= 1, got {self.lookback_rounds!r}"
            )
        _check_choice("solver", self.solver, ("ipopt", "fatrop"))
        _check_choice("slot_pick", self.slot_pick, ("nearest", "directions"))
        _check_positive("margin", self.margin, allow_zero=True)
        if not isinstance(self.obstacle_slots, int) or not 1 <= self.obstacle_slots <= 64:
            raise ConfigError(
                f"planner option obstacle_slots: integer in [1, 64], got {self.obstacle_slots!r}"
            )
        if not isinstance(self.one_sided_duals, bool):
            raise ConfigError(
                f"planner option one_sided_duals: must be true or false, got {self.one_sided_duals!r}"
            )
        _check_positive("obstacle_radius", self.obstacle_radius)
        _check_positive("start_region_radius", self.start_region_radius, allow_zero=True)
        _check_positive("effort_weight", self.effort_weight, allow_zero=True)
        if not isinstance(self.max_iter, int) or self.max_iter < 1:
            raise ConfigError(
                f"planner option max_iter: must be a positive integer, got {self.max_iter!r}"
            )
        _check_positive("time_limit", self.time_limit)
        _check_positive("plan_budget", self.plan_budget)
        if not is_int_in(self.close_gaps, 0):
            raise ConfigError(
                f"planner option close_gaps: must be an integer >= 0, got {self.close_gaps!r}"
            )
        _check_positive("grid_resolution", self.grid_resolution)
        try:
            starts = tuple(float(f) for f in self.extra_starts)
        except (TypeError, ValueError):
            starts = None
        if starts is None or not all(0 < f <= 1 for f in starts):
            raise ConfigError(
                "planner option extra_starts: a list of speed fractions in (0, 1], got"
                f" {self.extra_starts!r}"
            )
        object.__setattr__(self, "extra_starts", starts)
        if not isinstance(self.slower_guesses, bool):
            raise ConfigError(
                f"planner option slower_guesses: must be true or false, got {self.slower_guesses!r}"
            )
        if not 0 < self.guess_speed_fraction <= 1:
            raise ConfigError(
                f"planner option guess_speed_fraction: must be in (0, 1], got {self.guess_speed_fraction!r}"
            )


#: A start counted observed as a whole (take-off, ``plan()``): no separate observed box or path.
_NOT_OBSERVED = dict.fromkeys(("observed_lo", "observed_hi", "observed_path", "past_views"))


@dataclass(frozen=True, eq=False)
class PlanningProblem:
    """Everything the planner needs, in the robot's belief.

    Attributes
    ----------
    model : the vehicle model (dynamics, limits, camera pose).
    family : the reactive-set family S_r(x) (eq. ReactEllipse).
    frustum : the camera's field of view (eq. SensorModel).
    x0 : (nx,) initial state. goal : (3,) goal position (reached at rest).
    bounds_lo, bounds_hi : (3,) plannable region (the server map's extent).
    boxes_lo, boxes_hi : (n, 3) known obstacles as axis-aligned boxes.
    start_region_lo, start_region_hi : (3,) axis-aligned box counted as observed (it contains the
        reactive set of the start state: the paper's safety theorem assumes S_r(x(0)) observed).
    occupancy : the belief map (used only for the graph-search guess), may be None.
    options : :class:`PlannerOptions`.
    observed_lo, observed_hi : (3,) the box the certificate and the tracking guard count as
        observed at the start, when it differs from the start region (None: the start region).
        A replan in flight sets it (:meth:`with_start`): the NLP's start region is grown to
        contain S_r(x0) so that node 0 is feasible, but only what the robot verified counts as
        observed (session 25: counting the grown box let a robot touch a wall the server had
        misplaced).
    observed_path : (m, 3) body centres along the reactive manoeuvre from ``x0`` (a replan in
        flight): the body swept along it counts as observed too, besides the box
        (:meth:`start_margins`). None: the box alone.
    past_views : (rotations (k, 3, 3), origins (k, 3)) of frames the camera took before the plan
        starts, each inserted into the belief (a replan in flight). The certificate counts them as
        views earlier than every point of the plan, as the tracking guard counts the frames
        taken. None: only the plan's own camera poses.
    """

    model: VehicleModel
    family: ReactiveSetFamily
    frustum: PinholeFrustum
    x0: np.ndarray
    goal: np.ndarray
    bounds_lo: np.ndarray
    bounds_hi: np.ndarray
    boxes_lo: np.ndarray
    boxes_hi: np.ndarray
    start_region_lo: np.ndarray
    start_region_hi: np.ndarray
    options: PlannerOptions = field(default_factory=PlannerOptions)
    controller: object | None = None
    occupancy: OccupancyMap | None = None
    name: str = ""
    observed_lo: np.ndarray | None = None
    observed_hi: np.ndarray | None = None
    observed_path: np.ndarray | None = None
    past_views: tuple[np.ndarray, np.ndarray] | None = None

    def __post_init__(self) -> None:
        for attr in (
            "x0",
            "goal",
            "bounds_lo",
            "bounds_hi",
            "boxes_lo",
            "boxes_hi",
            "start_region_lo",
            "start_region_hi",
        ):
            arr = np.array(getattr(self, attr), dtype=float)
            arr.flags.writeable = False
            object.__setattr__(self, attr, arr)
        if (self.observed_lo is None) != (self.observed_hi is None):
            raise ConfigError("observed_lo, observed_hi: give both or neither")
        for attr in ("observed_lo", "observed_hi"):
            if getattr(self, attr) is not None:
                arr = np.array(getattr(self, attr), dtype=float)
                if arr.shape != (3,) or not np.all(np.isfinite(arr)):
                    raise ConfigError(f"{attr}: expected 3 finite numbers, got {arr}")
                arr.flags.writeable = False
                object.__setattr__(self, attr, arr)
        if self.observed_path is not None:
            path = np.array(self.observed_path, dtype=float)
            if path.ndim != 2 or path.shape[1:] != (3,) or not len(path):
                raise ConfigError(f"observed_path: expected (m >= 1, 3) points, got {path.shape}")
            if not np.all(np.isfinite(path)):
                raise ConfigError("observed_path: every point must be finite")
            path.flags.writeable = False
            object.__setattr__(self, "observed_path", path)
        if self.past_views is not None:
            object.__setattr__(self, "past_views", _camera_poses(self.past_views))
        if self.x0.shape != (self.model.nx,):
            raise ConfigError(f"x0: expected shape ({self.model.nx},), got {self.x0.shape}")
        if not np.all(np.isfinite(self.x0)):
            raise ConfigError(f"x0: must be finite, got {self.x0}")
        if self.goal.shape != (3,) or not np.all(np.isfinite(self.goal)):
            raise ConfigError(f"goal: expected 3 finite numbers, got {self.goal}")
        if self.boxes_lo.size == 0:
            object.__setattr__(self, "boxes_lo", np.zeros((0, 3)))
            object.__setattr__(self, "boxes_hi", np.zeros((0, 3)))
        if self.boxes_lo.shape != self.boxes_hi.shape or self.boxes_lo.ndim != 2:
            raise ConfigError(
                f"boxes: lo/hi shapes differ or are not (n, 3): {self.boxes_lo.shape}"
            )

    @property
    def box_index(self) -> BoxIndex:
        """Spatial index over the known obstacle boxes (built on first use, shared by problems
        with equal boxes): every distance, segment and sight-line query of the planner and the
        certificate goes through it."""
        index = self.__dict__.get("_box_index")
        if index is None:
            index = BoxIndex.of(self.boxes_lo, self.boxes_hi)
            object.__setattr__(self, "_box_index", index)
        return index

    @property
    def observed_start(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) of the box counted as observed at the start by the certificate and the guard:
        ``observed_lo/hi`` when set, else the start region."""
        if self.observed_lo is not None:
            return self.observed_lo, self.observed_hi
        return self.start_region_lo, self.start_region_hi

    def start_margins(self, points: np.ndarray, r: float) -> np.ndarray:
        """How far a ball of radius ``r`` about each of ``points`` (n, 3) lies inside what counts
        as observed at the start (>= 0: inside): the box :attr:`observed_start`, or the body swept
        along :attr:`observed_path` (minus the distance to that path). The two count as a union,
        never as their bounding box (a region narrower than the body beside unobserved space must
        not count the whole slab the body pokes into)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        lo, hi = self.observed_start
        margin = np.minimum(pts - lo, hi - pts).min(axis=1) - r
        if self.observed_path is not None and len(pts):
            outside = np.flatnonzero(margin < 0.0)
            if len(outside):
                near = -polyline_distance(pts[outside], self.observed_path)
                margin[outside] = np.maximum(margin[outside], near)
        return margin

    def manoeuvre_path(self, x0: np.ndarray) -> np.ndarray:
        """(m, 3) positions of the body centre along the reactive manoeuvre from ``x0`` (its
        rollout at 0.01 s, repeated positions dropped; without a controller, ``x0``'s alone)."""
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (self.model.nx,) or not np.all(np.isfinite(x0)):
            raise ConfigError(
                f"manoeuvre_path: x0 must be {self.model.nx} finite numbers, got {x0}"
            )
        p = np.asarray(self.model.position(x0), dtype=float).reshape(1, 3)
        if self.controller is not None:
            _, traj = self.controller.rollout_batch(x0[None], dt=0.01)
            p = np.asarray(self.model.position(np.asarray(traj, dtype=float)[0]), dtype=float)
            p = p.reshape(-1, 3)
        moved = np.ones(len(p), bool)
        moved[1:] = np.abs(np.diff(p, axis=0)).max(axis=1) > 1e-12
        return p[moved]

    @property
    def start_position(self) -> np.ndarray:
        return np.asarray(self.model.position(self.x0), dtype=float)

    def with_options(self, **changes: object) -> PlanningProblem:
        """A copy with some options replaced (validated)."""
        from dataclasses import replace

        updated = replace(self, options=replace(self.options, **changes))
        if "start_region_radius" in changes:
            lo, hi = start_region(
                self.model, self.family, self.x0, updated.options.start_region_radius
            )
            updated = replace(updated, start_region_lo=lo, start_region_hi=hi, **_NOT_OBSERVED)
        return updated

    def with_start(
        self,
        x0: np.ndarray,
        half_size: float | None = None,
        region: tuple[np.ndarray, np.ndarray] | None = None,
        past_views: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> PlanningProblem:
        """A copy starting from another state (for replanning), keeping the obstacles.

        The observed start box is ``region`` (lo, hi) if given, else a cube of ``half_size``
        around the new start (default: the option ``start_region_radius``); callers that know what
        the camera saw (the closed loop) pass the largest box their map has observed. Either is
        grown to contain S_r(x0) (see :func:`start_region`) for the NLP. With ``region``, the
        certificate and the guard count as observed only ``region`` and the body along the
        reactive manoeuvre from ``x0`` (:meth:`manoeuvre_path`; at rest, the body where it is), not
        the fitted set's slack around it (``observed_lo/hi``, ``observed_path``); and, given,
        ``past_views`` (frames the camera took, inserted into the belief) count as earlier views.
        """
        from dataclasses import replace

        x0 = np.asarray(x0, dtype=float)
        if region is not None:
            r_lo, r_hi = (np.asarray(v, dtype=float) for v in region)
            if r_lo.shape != (3,) or r_hi.shape != (3,) or not np.all(np.isfinite([r_lo, r_hi])):
                raise ConfigError(
                    f"with_start: region must be two finite 3-vectors, got {region!r}"
                )
            if np.any(r_lo > r_hi):
                raise ConfigError(f"with_start: region lo must be <= hi, got {region!r}")
            lo, hi = start_region(self.model, self.family, x0, 0.0)
            lo, hi = np.minimum(lo, r_lo), np.maximum(hi, r_hi)
            return replace(
                self,
                x0=x0,
                start_region_lo=lo,
                start_region_hi=hi,
                observed_lo=r_lo,
                observed_hi=r_hi,
                observed_path=self.manoeuvre_path(x0),
                past_views=past_views,
            )
        half = self.options.start_region_radius if half_size is None else half_size
        lo, hi = start_region(self.model, self.family, x0, half)
        return replace(self, x0=x0, start_region_lo=lo, start_region_hi=hi, **_NOT_OBSERVED)


def _camera_poses(views: object) -> tuple[np.ndarray, np.ndarray]:
    """(rotations (k, 3, 3), origins (k, 3)), read-only, from ``views`` (two arrays). A view's
    frustum is read through its rotation: anything but a rotation would count unseen space seen."""
    try:
        R, o = (np.array(v, dtype=float) for v in views)
        R, o = R.reshape(-1, 3, 3), o.reshape(-1, 3)
    except (TypeError, ValueError):
        raise ConfigError(f"past_views: expected (rotations, origins), got {views!r}") from None
    off = np.abs(np.einsum("kji,kjl->kil", R, R) - np.eye(3)).max(initial=0.0)
    if (
        len(R) != len(o)
        or not (off <= 1e-6 and np.all(np.isfinite(o)))
        or np.any(np.linalg.det(R) < 0)
    ):
        raise ConfigError(
            f"past_views: expected k proper rotations (R^T R = I, det +1; off by {off:.2g}) and k"
            f" finite origins, got {len(R)} and {len(o)}"
        )
    R.flags.writeable = o.flags.writeable = False
    return R, o


def start_region(
    model: VehicleModel, family: ReactiveSetFamily, x0: np.ndarray, half_size: float
) -> tuple[np.ndarray, np.ndarray]:
    """The box counted as observed at the start: a cube of ``half_size`` around the start position,
    grown to contain the reactive set S_r(x0) (the paper's safety theorem needs S_r(x(0)) observed
    before the robot moves)."""
    p0 = np.asarray(model.position(x0), dtype=float)
    c, M = family.ellipsoid(np.asarray(x0, dtype=float))
    c, M = np.asarray(c, dtype=float).ravel(), np.asarray(M, dtype=float)
    extent = np.linalg.norm(M, axis=0)  # support of E along +-e_d is c_d +- |M e_d|
    lo = np.minimum(p0 - half_size, c - extent)
    hi = np.maximum(p0 + half_size, c + extent)
    return lo, hi


def rest_footprint(scenario: Scenario, **options: object) -> float:
    """Half-width (m) of the narrowest corridor the secure planner can use: the largest semi-axis
    of the reactive set at rest at the start (plus how far its centre sits off the body, in the
    horizontal plane), plus the planner's margin. Corridors narrower than twice this, in the
    belief map, hold no plan the secure planner or its certificate accepts.

    ``options``: planner options as for :func:`problem_from_scenario` (``reactive_family``,
    ``controller``, ``margin`` are the ones that matter)."""
    from secure3d.dynamics import model_from_spec
    from secure3d.reactive.family_store import family_for

    spec = scenario.planner
    margin = float(options.get("margin", spec.margin))  # type: ignore[arg-type]
    _check_positive("margin", margin, allow_zero=True)
    model = model_from_spec(scenario.vehicle, scenario.camera)
    family = family_for(
        model,
        controller=str(options.get("controller", spec.controller)),
        kind=str(options.get("reactive_family", spec.reactive_family)),
    )
    x = model.rest_state(np.array(scenario.start.position, dtype=float), scenario.start.yaw)
    c, M = family.ellipsoid(x)
    offset = float(np.linalg.norm((np.asarray(c) - x[:3])[:2]))
    return float(np.linalg.eigvalsh(np.asarray(M)).max()) + offset + margin


def problem_from_scenario(
    scenario: Scenario,
    belief: OccupancyMap | None = None,
    x0: np.ndarray | None = None,
    obstacle_boxes: tuple[np.ndarray, np.ndarray] | None = None,
    **options: object,
) -> PlanningProblem:
    """Build the planning problem of a scenario in the robot's belief.

    Parameters
    ----------
    scenario : the scenario (vehicle, camera, start, goal, planner settings).
    belief : the robot's map; default: the server's claim only (:func:`secure3d.world.attacks.belief_map`).
    x0 : start state; default: the scenario's start.
    obstacle_boxes : (lo, hi) obstacle boxes; default: the belief's known obstacle boxes. A caller
        that replaces them before planning (the closed loop) passes empty ones and saves a merge.
    **options : :class:`PlannerOptions` fields overriding the scenario's planner settings, and
        ``min_obstacle_size`` (m) overriding the scenario's: the frustum's far limit is the observed
        range it gives (:func:`observed_frustum`), never the camera's raw ``max_range``.
    """
    from dataclasses import fields

    from secure3d.dynamics import model_from_spec
    from secure3d.reactive.controllers import BrakingController
    from secure3d.reactive.family_store import family_for
    from secure3d.world.attacks import belief_map

    spec = scenario.planner
    base = {
        "nodes": spec.nodes,
        "lookback": spec.lookback,
        "lookback_steps": spec.lookback_steps,
        "solver": spec.solver,
        "margin": spec.margin,
        "max_iter": spec.max_iter,
        "extra_starts": spec.extra_starts,
    }
    known = {f.name for f in fields(PlannerOptions)}
    unknown = set(options) - known - {"reactive_family", "controller", "min_obstacle_size"}
    if unknown:
        raise ConfigError(f"unknown planner option(s): {sorted(unknown)}; known: {sorted(known)}")
    kind = str(options.pop("reactive_family", spec.reactive_family))
    controller_name = str(options.pop("controller", spec.controller))
    min_size = options.pop("min_obstacle_size", spec.min_obstacle_size)
    base.update(options)
    opts = PlannerOptions(**base)

    model = model_from_spec(scenario.vehicle, scenario.camera)
    family = family_for(model, controller=controller_name, kind=kind)
    _check_positive("min_obstacle_size", min_size)
    res, edge = scenario.server_map.resolution, scenario.planner.edge_allowance
    frustum = observed_frustum(scenario.camera, res, float(min_size), edge_allowance=edge)
    if x0 is None:
        s = scenario.start
        x0 = model.initial_state(np.array(s.position), np.array(s.velocity), s.yaw)
    if belief is None:
        belief = belief_map(scenario)
    if obstacle_boxes is None:
        lo, hi = belief.known_obstacle_boxes(close_gaps=opts.close_gaps)
    else:
        lo, hi = (np.asarray(b, dtype=float).reshape(-1, 3) for b in obstacle_boxes)
    start_lo, start_hi = start_region(model, family, x0, opts.start_region_radius)
    return PlanningProblem(
        model=model,
        family=family,
        frustum=frustum,
        x0=x0,
        goal=np.array(scenario.goal.position),
        bounds_lo=np.array(scenario.world.bounds.lo),
        bounds_hi=np.array(scenario.world.bounds.hi),
        boxes_lo=lo,
        boxes_hi=hi,
        start_region_lo=start_lo,
        start_region_hi=start_hi,
        options=opts,
        controller=BrakingController(model),
        occupancy=belief,
        name=scenario.name,
    )
