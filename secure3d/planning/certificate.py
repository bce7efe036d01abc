"""The independent safety certificate: does a plan satisfy the paper's definition of *safe*?

A planned path is safe (paper, Definition before Theorem "Safety") if every reactive set S_r(x(t)) was
observed before t (eq. FullConstraint: S_r(x(t)) ⊂ ∪_{τ<t} S_s(x(τ))) and never meets a known
obstacle. The NLP enforces a tightened, ellipsoidal version of this at the nodes; this module checks
the real thing, with none of the NLP's constraint code:

- time is sampled densely, between collocation nodes too (the paper's Prop. 1 is about exactly this);
- the reactive manoeuvre is *simulated* from every sampled state with the actual controller (not the
  fitted ellipsoid), and every manoeuvre point, grown by the body radius, is checked;
- "observed" means: inside the start box, or inside the camera's field of view at an earlier sampled
  time (tested in the camera frame from the FOV angles and range, not from half-spaces) with a line
  of sight from that camera that no known obstacle blocks (beyond the paper: walls occlude);
- "clear" means: outside every known obstacle box and inside the map bounds, by the body radius.

Sampling the union of frusta at discrete earlier times gives an inner approximation of the paper's
continuous union, so passing here is never easier than passing the paper's condition.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from secure3d.errors import PlanningError
from secure3d.geometry.box_index import BoxIndex
from secure3d.planning.interrupt import BudgetSpent, deadline_passed
from secure3d.planning.result import Certificate, PlanResult, Violation
from secure3d.planning.trajectory import interpolate
from secure3d.validation import is_real

#: Candidate earlier views tried per manoeuvre point before the exhaustive pass.
TOP_VIEWS = 8


@dataclass(frozen=True)
class CertificateSettings:
    """How densely the certificate samples.

    dt : spacing of the checked trajectory times (s).
    rollout_dt : integration step of the simulated reactive manoeuvres (s).
    points_per_manoeuvre : manoeuvre points kept per sampled state (evenly spaced along the rollout,
        always including the first and last).
    tolerance : numerical slack on every margin (m).
    """

    dt: float = 0.02
    rollout_dt: float = 0.01
    points_per_manoeuvre: int = 16
    tolerance: float = 1e-6

    def __post_init__(self) -> None:
        for name in ("dt", "rollout_dt", "tolerance"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise PlanningError(f"certificate setting {name}: must be > 0, got {v!r}")
        if self.points_per_manoeuvre < 2:
            raise PlanningError(
                f"certificate setting points_per_manoeuvre: must be >= 2, got {self.points_per_manoeuvre}"
            )


#: :attr:`Certificate.views` of a point observed by frame ``j`` of those taken before the plan
#: (``PlanningProblem.past_views``) is ``PAST_VIEW - j``; -1: the start region, -2: not observed in
#: time, >= 0: a plan camera.
PAST_VIEW = -3


def _box_index(problem: object) -> BoxIndex:
    """The spatial index of the problem's known boxes (exact: the same answers as scanning them)."""
    index = getattr(problem, "box_index", None)
    return index if index is not None else BoxIndex.of(problem.boxes_lo, problem.boxes_hi)


def _manoeuvres(controller: object, model: object, X: np.ndarray, dt: float, m: int) -> np.ndarray:
    """(N, m, 3) positions along the reactive manoeuvre started from each state in X."""
    out = controller.rollout_batch(X, dt=dt)
    traj = out[1] if isinstance(out, tuple) else out
    traj = np.asarray(traj, dtype=float)  # (N, T, nx)
    idx = np.unique(np.linspace(0, traj.shape[1] - 1, m).round().astype(int))
    sel = traj[:, idx, :]
    # rollouts that stopped early are padded by repeating their final state: harmless duplicates
    pos = np.asarray(model.position(sel.reshape(-1, sel.shape[-1])), dtype=float)
    return pos.reshape(sel.shape[0], sel.shape[1], 3)


#: Work (camera margins; a sight-cone test counts ``_certificate_kernel.CONE_WORK``) the view search
#: does between two looks at the plan call's deadline: 41 ms median, 0.13 s at most on that plan.
#: The cost of a point varies by orders of magnitude (a point every earlier camera frames but none
#: sees clearly tests a cone per camera: 3.4 ms against microseconds), so a fixed number of points
#: between looks overran a 10 s budget by 1.6 s on an occluded 70 s plan (issue 16).
VIEW_WORK = 1 << 24


def _clear_views(
    points: np.ndarray,
    owner: np.ndarray,
    R: np.ndarray,
    o: np.ndarray,
    frustum: object,
    radius: float,
    lo: np.ndarray,
    hi: np.ndarray,
    tol: float,
    index: BoxIndex | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each ball of ``radius`` at ``points[i]``, seen from the cameras (R, o) of the samples
    before ``owner[i]``: whether one sees the whole ball with a sight cone clear of the boxes, that
    camera's margin, and the best margin ignoring occlusion (-inf: no earlier camera).

    A camera's margin is computed in its own frame (x right, y down, z forward) from the FOV angles
    and the sensor range, independently of the NLP's half-space code: the smallest of the distances
    inside the horizontal and vertical sides (an observed field of view's: ``side_margin``,
    ``side_offset``, ``side_shrink``), the near face if any and the far limit, minus the radius.
    Positive: the whole ball is inside the (observed) field of view."""
    from secure3d.planning._certificate_kernel import best_clear_views

    if index is None:
        index = BoxIndex.of(lo, hi)

    if frustum.principal_x != 0.5 or frustum.principal_y != 0.5:
        raise PlanningError("certify: the views' margins need a centred principal point")
    sides = np.array([frustum.side_margin, frustum.side_offset, frustum.near])
    points = np.ascontiguousarray(points, dtype=float)
    n = len(points)
    found, view = np.zeros(n, dtype=bool), np.full(n, -1, dtype=np.int64)
    best, raw = np.full(n, -np.inf), np.full(n, -np.inf)
    args = (
        points,
        np.ascontiguousarray(owner, dtype=np.int64),
        np.ascontiguousarray(R, dtype=float),
        np.ascontiguousarray(o, dtype=float),
        *frustum.side_plane_angles(),
        sides,
        float(frustum.far),
        frustum.far_kind == "range",
        float(radius),
        index.lo,
        index.hi,
        index.tree,
        float(tol),
        TOP_VIEWS,
        found,
        best,
        raw,
        view,
    )
    done = best_clear_views(*args, 0, VIEW_WORK)
    while done < n:
        if deadline_passed():
            raise BudgetSpent("the plan call's budget was spent while certifying")
        done = best_clear_views(*args, done, VIEW_WORK)
    return found, best, raw, view


@dataclass(frozen=True, eq=False)
class SampledPlan:
    """A plan read densely: sample times (n,), manoeuvre points (n*m, 3) with the sample each belongs
    to (owner), and the camera pose (rotations (n, 3, 3), origins (n, 3)) at every sample."""

    times: np.ndarray
    points: np.ndarray
    owner: np.ndarray
    rotations: np.ndarray
    origins: np.ndarray


def sample_plan(
    plan: PlanResult,
    problem: object,
    *,
    controller: object | None = None,
    settings: CertificateSettings | None = None,
) -> SampledPlan:
    """Sample a plan densely in time (between nodes too) and simulate the reactive manoeuvre from
    every sample with the actual controller."""
    settings = settings or CertificateSettings()
    if len(plan.times) < 2:
        raise PlanningError("certify: the plan has no trajectory (did planning fail?)")
    model = problem.model
    controller = controller if controller is not None else problem.controller
    if controller is None:
        raise PlanningError("certify: no reactive controller given")
    T = plan.final_time
    t = np.unique(np.concatenate([np.arange(0.0, T, settings.dt), plan.times, [T]]))
    X, _ = interpolate(model, plan.times, plan.states, plan.controls, t)
    pts = _manoeuvres(controller, model, X, settings.rollout_dt, settings.points_per_manoeuvre)
    owner = np.repeat(np.arange(len(t)), pts.shape[1])
    R, o = (np.asarray(a, dtype=float) for a in model.camera_pose(X))
    return SampledPlan(times=t, points=pts.reshape(-1, 3), owner=owner, rotations=R, origins=o)


#: Manoeuvre points the certificate judges between two looks at the plan call's budget (about
#: 0.1-0.2 s of work): a certificate inside a plan call stops with :class:`BudgetSpent` once the
#: budget has passed instead of running on past it (issue 16: a quadrotor call overran a 10 s budget
#: by 1 s certifying a 30,000-point plan). Each point is judged on its own, so the chunks give the
#: same answers as one pass.
CHUNK_POINTS = 4096


#: Manoeuvre points judged at a time when only the first failure is asked for (``first_only``):
#: 32 samples of 16 points, so that little is judged past it.
FIRST_CHUNK_POINTS = 512


def _judge_in_chunks(
    flat: np.ndarray,
    owner: np.ndarray,
    R: np.ndarray,
    o: np.ndarray,
    problem: object,
    r: float,
    tol: float,
    first_only: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_judge_points` over :data:`CHUNK_POINTS` points at a time, raising
    :class:`~secure3d.planning.interrupt.BudgetSpent` before a chunk once the plan call's deadline
    has passed (outside a plan call there is none).

    With ``first_only``, the points (``owner`` sorted, as :func:`sample_plan` orders them) are
    judged in time order, :data:`FIRST_CHUNK_POINTS` at a time, up to the last point of the first
    sample with a failing point, and the answers cover that prefix only: everything
    :func:`_first_violation` needs to name the same violation as a pass over all points."""
    index = _box_index(problem)
    end, step, obstacle = len(flat), CHUNK_POINTS, None
    if first_only:
        step = FIRST_CHUNK_POINTS
        # no point after the first sample with an obstacle hit can fail first: stop there at most
        obstacle = _obstacle_margins(flat, problem, r, index)
        hits = obstacle < -tol
        if hits.any():
            end = int(np.searchsorted(owner, owner[np.argmax(hits)], side="right"))
    parts, starts, a = [], [], 0
    while a < max(end, 1):
        if deadline_passed():
            raise BudgetSpent("the plan call's budget was spent while certifying")
        b = min(a + step, max(end, 1))
        margins = None if obstacle is None else obstacle[a:b]
        part = _judge_points(flat[a:b], owner[a:b], R, o, problem, r, tol, index, margins)
        parts.append(part)
        starts.append(a)
        bad = np.minimum(part[0], part[1]) < -tol
        if first_only and bad.any():
            end = min(end, int(np.searchsorted(owner, owner[a + np.argmax(bad)], side="right")))
        a = b
    if len(parts) == 1:
        out = parts[0]
    else:
        out = (
            np.concatenate([p[0] for p in parts]),
            np.concatenate([p[1] for p in parts]),
            np.concatenate([p[2] for p in parts]),
            np.concatenate([p[3] + a for p, a in zip(parts, starts, strict=True)]),
            np.concatenate([p[4] for p in parts]),
        )
    if len(out[0]) <= end:
        return out
    needed = out[3] < end  # the last chunk went past the first failing sample: cut there
    return out[0][:end], out[1][:end], out[2][:end], out[3][needed], out[4][needed]


def _obstacle_margins(flat: np.ndarray, problem: object, r: float, index: BoxIndex) -> np.ndarray:
    """(n,) how far each point of ``flat`` (n, 3), grown by ``r``, stays from the boxes of
    ``index`` (0 inside one) and inside the map bounds of ``problem``."""
    dist = np.maximum(index.min_distance(flat), 0.0)  # 0 inside a box
    in_map = np.minimum(flat - problem.bounds_lo, problem.bounds_hi - flat).min(axis=1)
    return np.minimum(dist, in_map) - r


def _judge_points(
    flat: np.ndarray,
    owner: np.ndarray,
    R: np.ndarray,
    o: np.ndarray,
    problem: object,
    r: float,
    tol: float,
    index: BoxIndex | None = None,
    obstacle_margin: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The certificate's test of manoeuvre points ``flat`` (n, 3), each seen only from the cameras
    (R, o) before ``owner``: (obstacle margin (n,), visibility margin (n,), the view that observes
    each point (-1: the start region), the points that needed a view, and which of those were
    inside an earlier field of view but occluded). ``index``: the problem's box index, if built;
    ``obstacle_margin``: the points' :func:`_obstacle_margins`, if computed already."""
    # ---- clear of known obstacles and inside the map -------------------------------------------
    index = _box_index(problem) if index is None else index
    if obstacle_margin is None:
        obstacle_margin = _obstacle_margins(flat, problem, r, index)

    # ---- observed before: start ball, or an earlier view with a clear line of sight -------------
    start_margin = problem.start_margins(flat, r)
    # The body ball is seen only if the whole cone of sight lines from the camera to it is clear.
    vis_margin = start_margin.copy()
    unresolved = np.flatnonzero(start_margin < -tol)
    occluded_only = np.zeros(len(unresolved), bool)
    view = np.full(len(flat), -1, dtype=np.int64)  # -1: the start region
    if len(unresolved):
        found, best, raw, view[unresolved] = _clear_views(
            flat[unresolved],
            owner[unresolved],
            R,
            o,
            problem.frustum,
            r,
            index.lo,
            index.hi,
            tol,
            index,
        )
        occluded_only = ~found & (raw > -tol)
        # never seen with a clear line of sight: 1 cm worse than the best (blocked) view, or -1 m
        # when no earlier view exists at all
        unseen = np.where(np.isfinite(raw), np.minimum(raw, 0.0) - 0.01, -1.0)
        vis_margin[unresolved] = np.maximum(start_margin[unresolved], np.where(found, best, unseen))
    return obstacle_margin, vis_margin, view, unresolved, occluded_only


def state_margin(
    x: np.ndarray,
    problem: object,
    rotations: np.ndarray,
    origins: np.ndarray,
    *,
    controller: object | None = None,
    settings: CertificateSettings | None = None,
) -> tuple[float, str]:
    """The certificate's test for one state: the reactive manoeuvre simulated from ``x`` (nx,) must
    stay clear of the problem's known obstacles and be observed, by the start region or by one of
    the camera poses ``rotations`` (k, 3, 3), ``origins`` (k, 3) with a clear sight cone, all by
    the body radius. Returns the smallest margin (m; >= -tolerance passes) and what limits it.

    This is what the tracking guard of the closed loop asks of the state the robot is really in
    (:mod:`secure3d.simulation.guard`); :func:`certify` asks it of every sampled planned state.
    """
    settings = settings or CertificateSettings()
    controller = controller if controller is not None else problem.controller
    model, tol = problem.model, settings.tolerance
    x = np.asarray(x, dtype=float)
    if x.shape != (model.nx,) or not np.all(np.isfinite(x)):
        raise PlanningError(
            f"state_margin: x must be {model.nx} finite numbers, got shape {x.shape}"
        )
    x = x.reshape(1, -1)
    pts = _manoeuvres(controller, model, x, settings.rollout_dt, settings.points_per_manoeuvre)[0]
    R = np.asarray(rotations, dtype=float).reshape(-1, 3, 3)
    o = np.asarray(origins, dtype=float).reshape(-1, 3)
    owner = np.full(len(pts), len(R), dtype=np.int64)  # every view given counts as earlier
    obstacle, visible, _, _, _ = _judge_points(pts, owner, R, o, problem, model.body_radius, tol)
    if obstacle.min() <= visible.min():
        return float(obstacle.min()), "its reactive manoeuvre meets a known obstacle"
    return float(visible.min()), "its reactive manoeuvre reaches space not observed before"


def _check_window(t_from: object, t_until: object) -> None:
    """A window of plan time to judge: numbers with ``t_from < t_until`` (``t_until`` may be inf).
    A NaN or reversed window would judge no point and pass the plan."""
    for name, v in (("t_from", t_from), ("t_until", t_until)):
        if not is_real(v, numpy=True) or np.isnan(v) or v == -np.inf:
            raise PlanningError(f"certify: {name} must be a number (t_until may be inf), got {v!r}")
    if not t_from < t_until:
        raise PlanningError(f"certify: t_until must be after t_from, got {t_from!r}, {t_until!r}")


def certify(
    plan: PlanResult,
    problem: object,
    *,
    controller: object | None = None,
    settings: CertificateSettings | None = None,
    t_from: float = 0.0,
    t_until: float = np.inf,
    sampled: SampledPlan | None = None,
    first_only: bool = False,
) -> Certificate:
    """Check a plan against the paper's safety definition, independently of the planner.

    Parameters
    ----------
    plan : the plan to judge (any planner's).
    problem : a :class:`~secure3d.planning.problem.PlanningProblem` giving the vehicle model, the
        camera frustum, the start ball and the known obstacles of the belief to judge against (pass
        an updated problem to re-certify the rest of a plan after the map changed).
    controller : the reactive controller whose manoeuvres are simulated (default: the problem's).
    settings : sampling density (:class:`CertificateSettings`).
    t_from : judge only the part of the plan from this time on (views before it still count): used
        to re-certify the rest of a plan in flight (Algorithm 1).
    t_until : judge only the part of the plan before this time: used in flight while a replan is
        deferred before a manoeuvre known to fail at ``t_until`` (only an earlier failure matters).
    sampled : the plan's sampled manoeuvres and camera poses (:func:`sample_plan`): they do not
        depend on the map, so re-certifying after every camera frame reuses them.
    first_only : stop judging after the first sample with a failing point (in flight, where only
        whether and where the rest of a plan first fails matters). ``ok`` and ``first_violation``
        are those of a full pass; a failing certificate's margins, ``n_points`` and ``views`` then
        cover the points up to that sample (the rest count as not shown: views -2).

    Returns
    -------
    Certificate
        ``ok``, the smallest margins and the first violation (time, point, reason).
    """
    settings = settings or CertificateSettings()
    _check_window(t_from, t_until)
    r = problem.model.body_radius
    tol = settings.tolerance
    if sampled is None:
        if deadline_passed():
            raise BudgetSpent("the plan call's budget was spent before certifying")
        sampled = sample_plan(plan, problem, controller=controller, settings=settings)
    t, n_t = sampled.times, len(sampled.times)
    kept, flat, owner = _window(sampled, t_from, t_until)
    k, R, o = _with_past_views(problem, sampled.rotations, sampled.origins)
    obstacle_margin, vis_margin, view, unresolved, occluded_only = _judge_in_chunks(
        flat, owner + k, R, o, problem, r, tol, first_only
    )
    judged = len(obstacle_margin)  # all of them, but with first_only a prefix through the failure
    kept, flat, owner = kept[:judged], flat[:judged], owner[:judged]
    view = _stored_views(view, k)
    margin = np.minimum(vis_margin, obstacle_margin)
    bad = margin < -tol
    views = np.full(len(sampled.points), -2, dtype=np.int64)
    views[kept] = np.where(bad, -2, view)  # bad covers every point not observed in time
    if len(margin) == 0:  # nothing left to judge (t_from past the end of the plan or t_until)
        return Certificate(True, np.inf, np.inf, np.inf, None, 0, 0, views, sampled)
    return Certificate(
        ok=not bad.any(),
        min_margin=float(margin.min()),
        min_visibility_margin=float(vis_margin.min()),
        min_obstacle_margin=float(obstacle_margin.min()),
        first_violation=_first_violation(
            bad, owner, t, flat, margin, obstacle_margin < -tol, unresolved, occluded_only
        ),
        n_samples=n_t,
        n_points=len(flat),
        views=views,
        sampled=sampled,
    )


def _window(
    sampled: SampledPlan, t_from: float, t_until: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sampled points of the part of the plan in [t_from, t_until) (views from before it
    still count): their indices into ``sampled.points`` (n,) int, the points (n, 3) and the index
    of each one's sample (n,) int."""
    t, owner = sampled.times, sampled.owner
    kept = np.flatnonzero((t[owner] >= t_from - 1e-9) & (t[owner] < t_until - 1e-9))
    return kept, sampled.points[kept], owner[kept]


def _with_past_views(
    problem: object, R: np.ndarray, o: np.ndarray
) -> tuple[int, np.ndarray, np.ndarray]:
    """(k, rotations, origins): the problem's ``past_views`` (k frames the camera took before the
    plan, a replan in flight) put before the plan's cameras ``R`` (n, 3, 3), ``o`` (n, 3), so that
    they count as earlier than every sample (the view search takes cameras before a point's
    owner, whose index moves up by k)."""
    past = getattr(problem, "past_views", None)
    if past is None or not len(past[0]):
        return 0, R, o
    return len(past[0]), np.concatenate([past[0], R]), np.concatenate([past[1], o])


def _stored_views(view: np.ndarray, k: int) -> np.ndarray:
    """Views of the cameras ``[past frames (k), plan cameras]`` as :attr:`Certificate.views` holds
    them: a plan camera's index in the sampled plan, ``PAST_VIEW - j`` for past frame ``j``."""
    return np.where(view >= k, view - k, np.where(view >= 0, PAST_VIEW - view, view))


def _view_origins(views: np.ndarray, sampled: SampledPlan, problem: object) -> np.ndarray | None:
    """(n, 3) the camera origin of each stored view ``views`` (n,) (each >= 0 or <= PAST_VIEW), or
    None when a past frame is named that ``problem`` does not hold."""
    past = getattr(problem, "past_views", None)
    j = PAST_VIEW - views[views <= PAST_VIEW]
    if len(j) and (past is None or j.max() >= len(past[1])):
        return None
    out = np.empty((len(views), 3))
    out[views >= 0] = sampled.origins[views[views >= 0]]
    if len(j):
        out[views <= PAST_VIEW] = past[1][j]
    return out


def _first_violation(
    bad: np.ndarray,
    owner: np.ndarray,
    t: np.ndarray,
    points: np.ndarray,
    margin: np.ndarray,
    hits_obstacle: np.ndarray,
    unresolved: np.ndarray,
    occluded_only: np.ndarray,
) -> Violation | None:
    """The earliest failing point and why it fails (None when no point fails).

    Parameters
    ----------
    bad, hits_obstacle : (n,) bool, per judged point: fails; its obstacle margin fails.
    owner : (n,) int, each point's sample; t : (n_t,) float, the sample times. points : (n, 3).
    margin : (n,) float, the smaller of the obstacle and visibility margins.
    unresolved : (m,) int, sorted indices of the points outside the start region (they need a view);
    occluded_only : (m,) bool, for those, inside an earlier field of view but occluded.
    """
    if not bad.any():
        return None
    k = int(np.flatnonzero(bad)[np.argmin(owner[bad])])
    if hits_obstacle[k]:
        reason = "reactive manoeuvre meets a known obstacle or leaves the map"
    else:
        pos = np.searchsorted(unresolved, k)
        hidden = pos < len(unresolved) and unresolved[pos] == k and occluded_only[pos]
        reason = (
            "manoeuvre point inside an earlier field of view but occluded by a known obstacle"
            if hidden
            else "manoeuvre point not observed at any earlier time"
        )
    return Violation(
        time=float(t[owner[k]]), point=points[k].copy(), reason=reason, margin=float(margin[k])
    )


def failing_nodes(cert: Certificate, times: np.ndarray) -> np.ndarray:
    """(K,) 1.0 at the nodes at either end of every interval of node ``times`` (K,) in which the
    certificate ``cert`` found a failing manoeuvre point (the node itself for a point at a node),
    else 0.0. A certificate without its sampled plan marks every node."""
    times = np.asarray(times, dtype=float)
    if times.ndim != 1 or len(times) < 2 or np.any(np.diff(times) <= 0.0):
        raise PlanningError(f"failing_nodes: node times must increase, got {times!r}")
    K = len(times)
    sampled = cert.sampled
    if cert.views is None or sampled is None or len(cert.views) != len(sampled.points):
        return np.ones(K)
    t = np.unique(sampled.times[sampled.owner[cert.views == -2]])
    out = np.zeros(K)
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, K - 1)
    out[i] = 1.0
    between = ~np.isclose(times[i], t, rtol=0.0, atol=1e-9)
    out[np.minimum(i[between] + 1, K - 1)] = 1.0
    return out
