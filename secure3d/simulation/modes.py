"""The closed loop's vocabulary: its modes, what changes them (one table), and its settings.

The state machine that uses them is :class:`secure3d.simulation.flight.Flight`.
"""

from __future__ import annotations

import enum
import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from secure3d.errors import SimulationError

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.result import PlanResult

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
#: A replan is refused (counted as a failed plan) when its path is longer than DETOUR_FACTOR times
#: the straight line to the goal plus DETOUR_SLACK_M, or when it would take longer than flying
#: DETOUR_FACTOR times that line at DETOUR_SLOWEST of the vehicle's top speed, plus DETOUR_SLACK_S.
#: (A diff drive's certified replan of 42.8 s for 5 m reversed again and again; secure replans
#: through a narrow gap legitimately crawl: 15-22 s for 5 m at 4 m/s top speed, so the time cap is
#: loose and the path cap does the work.)
DETOUR_FACTOR = 4.0
DETOUR_SLACK_M = 3.0
DETOUR_SLOWEST = 0.1
DETOUR_SLACK_S = 10.0
#: A replan from a moving robot is refused too (it brakes and plans from rest, Algorithm 1's lines
#: 4-7) when it would reach the goal later than braking to rest, plus SLOW_REPLAN_FACTOR times the
#: time the plan it replaces had left, plus SLOW_REPLAN_SLACK_S. A forest campaign's quadrotor,
#: replanning at 5 m/s round a tree it had just seen, took a plan that swung 4.7 m wide (8.56 s,
#: where the old plan had 2.16 s left); braking (1.07 s) and planning from rest took 4.56 s.
SLOW_REPLAN_FACTOR = 2.5
#: At rest near the goal, when the plan to the goal itself failed, the next plan aims at the point
#: this fraction of the goal tolerance from the goal, on the robot's side (see :func:`goal_edge`).
GOAL_EDGE_FRACTION = 0.7
SLOW_REPLAN_SLACK_S = 1.0


class Mode(enum.Enum):
    """What the robot is doing."""

    FOLLOW = "follow"  # line 3: tracking a certified plan
    BRAKE = "brake"  # lines 5-6: the reactive (evasive) manoeuvre, until at rest
    SCAN = "scan"  # at rest, turning to look around before replanning
    HOLD = "hold"  # at rest, replanning every REPLAN_RETRY s (line 7: go to line 1)
    EXPLORE = "explore"  # the map denies every route: following a plan to a point to look from
    RETREAT = "retreat"  # at rest overlapping a known obstacle: backing off it in a straight line


class Trigger(enum.Enum):
    """Why the mode changes."""

    PLANNED = "a certified plan"  # line 1 succeeded
    UNSAFE = "the plan is no longer safe and no certified replan"  # line 4
    OFF_TUBE = "the state left the certified tube"  # the tracking guard
    STOPPED = "at rest"  # line 7
    STOPPED_LOOK = "at rest, look around"
    LOOKED = "looked around"
    STUCK = "replans at rest keep failing"
    DENIED = "the map shows no route: go and look at the claim that closes it"
    ARRIVED = "at the point to look from"
    OVERLAPS = "at rest, the body overlaps (or, replans failing, nears) a known obstacle: back off"
    BACKED_OFF = "backed off the known obstacle"


#: Every mode change there is: (mode, trigger) -> next mode. Anything else is a bug and raises.
TRANSITIONS: dict[tuple[Mode, Trigger], Mode] = {
    (Mode.HOLD, Trigger.PLANNED): Mode.FOLLOW,
    (Mode.FOLLOW, Trigger.UNSAFE): Mode.BRAKE,
    (Mode.FOLLOW, Trigger.OFF_TUBE): Mode.BRAKE,
    (Mode.BRAKE, Trigger.STOPPED): Mode.HOLD,
    (Mode.BRAKE, Trigger.STOPPED_LOOK): Mode.SCAN,
    (Mode.SCAN, Trigger.LOOKED): Mode.HOLD,
    (Mode.HOLD, Trigger.STUCK): Mode.SCAN,
    (Mode.HOLD, Trigger.DENIED): Mode.EXPLORE,
    (Mode.EXPLORE, Trigger.ARRIVED): Mode.SCAN,  # turn to face the claim, then replan
    (Mode.EXPLORE, Trigger.UNSAFE): Mode.BRAKE,
    (Mode.EXPLORE, Trigger.OFF_TUBE): Mode.BRAKE,
    (Mode.HOLD, Trigger.OVERLAPS): Mode.RETREAT,  # see secure3d.simulation.retreat
    (Mode.RETREAT, Trigger.BACKED_OFF): Mode.HOLD,
    (Mode.RETREAT, Trigger.UNSAFE): Mode.BRAKE,  # the next step would leave the checked places
}
#: The modes in which the robot flies a certified plan (re-certified and guarded).
FLYING = (Mode.FOLLOW, Mode.EXPLORE)
#: Explorations one run may make (each flies to a point to look from, then replans; a look at the
#: same claim again goes nearer, see :func:`~secure3d.simulation.explore.nearer_look`).
MAX_EXPLORATIONS = 5
#: Retreats one run may make (:mod:`secure3d.simulation.retreat`).
MAX_RETREATS = 3


@dataclass(frozen=True)
class RunSettings:
    """How one closed-loop run is flown (see :func:`secure3d.simulation.closed_loop.simulate`).

    Attributes
    ----------
    dt, frame_period, time_limit : simulation step, camera frame period and run length (s).
    goal : (3,) float, where the run ends (m).
    max_replans : give up (robot holds still) after this many failed or successful replans. It
        also gives up after ``2 * STUCK_RETRIES`` failed replans in a row at rest, having looked
        around once after ``STUCK_RETRIES`` of them (the same problem fails the same way).
    look_around : after a take-over (and after every failed replan), turn the camera half a field
        of view to either side at rest before replanning (see
        :func:`~secure3d.simulation.closed_loop.scan_headings`).
    replan_in_flight : when new evidence breaks the rest of the plan, first try to replan from the
        moving state (the solve takes no simulated time); brake only if that fails.
    replan_latency : simulated seconds a replan in flight takes (0: instantaneous). With latency L
        the robot plans from where its current plan puts it L seconds later, keeps following that
        plan meanwhile, and switches at t + L; if the current plan's first uncertified manoeuvre
        comes before the switch, it brakes instead (take-over).
    replan_defer : seconds (0: replan at once). When new evidence breaks the plan but its first
        failing manoeuvre is more than this far ahead, keep following the plan (certified up to
        that manoeuvre) and replan this long before it, or sooner if later frames bring it closer.
        A hidden obstacle revealed a few voxels per frame then costs one replan, made with more of
        it seen, instead of one per frame. Not combined with ``replan_latency``.
    frame_log_every, belief_log_every : decimation of camera frames and belief voxels in the
        recording.
    seed : the run's seed (camera noise and dropout). wall0 : wall clock at the run's start (s).
    disturbance : ``(t, x, u) -> (x, u)`` applied before every integration step, or None.
    explore : fly certified plans to look at the claim that blocks the shortest route when the
        map shows no route because of claims the camera has not checked.
    """

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
    disturbance: Callable[[float, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]] | None = (
        None
    )
    explore: bool = True


@dataclass(frozen=True, eq=False)
class Followed:
    """A plan and what it was certified on: the simulation time it started and its problem."""

    plan: PlanResult
    start: float
    problem: object


def hold_after(model: object, plan: PlanResult) -> tuple[np.ndarray, np.ndarray]:
    """The reference (x (nx,), u (nu,)) once ``plan`` has ended: at rest where it ends, level, its
    heading kept, with the model's nominal control (hover, or no acceleration).

    The last node's own state and control are no hold: a minimum-time plan ends mid-manoeuvre (a
    quadrotor's last node tilted at full thrust), and fed forward for ever they pushed the robot
    off the goal, out of the plan's last reactive set (forest variant 80: 2.1 m, at up to 2.9 m/s,
    after passing 6 cm from the goal at 1.6 m/s).
    """
    x_end = np.asarray(plan.states[-1], dtype=float)
    position = np.asarray(model.position(x_end), dtype=float).ravel()
    x = model.rest_state(position, float(model.yaw(x_end)))
    return x, model.nominal_control(x)


def detour_time_limit(line: float, max_speed: float) -> float:
    """The longest replan (s) :func:`detour_reason` accepts for ``line`` m to the goal."""
    return DETOUR_FACTOR * line / (DETOUR_SLOWEST * max_speed) + DETOUR_SLACK_S


def slow_replan_limit(stop_time: float, time_left: float) -> float:
    """The longest replan (s) :func:`slow_replan_reason` accepts (arguments as there)."""
    return stop_time + SLOW_REPLAN_FACTOR * max(time_left, 0.0) + SLOW_REPLAN_SLACK_S


def replan_time_limit(
    p0: np.ndarray,
    goal: np.ndarray,
    max_speed: float,
    braking: tuple[float, float] | None,
    route: float = float("nan"),
) -> float:
    """The longest replan (s) from ``p0`` (3,) to ``goal`` (3,) that neither
    :func:`detour_reason` (with the same ``route``) nor, given ``braking`` = (stop time, time left
    on the old plan), :func:`slow_replan_reason` refuses for its duration. A caller that learns
    the route only from the plan passes ``route=np.inf``: then only braking limits it."""
    p, g = np.asarray(p0, dtype=float), np.asarray(goal, dtype=float)
    if p.shape != (3,) or g.shape != (3,) or not np.all(np.isfinite([*p, *g])):
        raise SimulationError(
            f"replan_time_limit: p0 and goal must be 3 finite numbers, got {p0!r}, {goal!r}"
        )
    if not (np.isfinite(max_speed) and max_speed > 0):
        raise SimulationError(f"replan_time_limit: max_speed must be > 0 (m/s), got {max_speed!r}")
    if braking is not None and not np.all(np.isfinite(braking)):
        raise SimulationError(f"replan_time_limit: braking times must be finite, got {braking!r}")
    top = detour_time_limit(_detour_reference(float(np.linalg.norm(g - p)), route), max_speed)
    return top if braking is None else min(top, slow_replan_limit(*braking))


def replan_refusal(
    positions: np.ndarray,
    final_time: float,
    p0: np.ndarray,
    goal: np.ndarray,
    max_speed: float,
    braking: tuple[float, float] | None,
    route: float = float("nan"),
) -> str | None:
    """Why a certified replan is not flown, or None: too long a detour (:func:`detour_reason`,
    arguments as there), or, given ``braking`` = (stop time, time left on the old plan) for a
    moving robot on its way to the goal, slower than braking and planning from rest."""
    why = detour_reason(positions, final_time, p0, goal, max_speed, route)
    if why is None and braking is not None:
        why = slow_replan_reason(final_time, *braking)
    return why


def _detour_reference(line: float, route: float) -> float:
    """What a detour is measured against: the route through the map when known (it is never
    shorter than the straight ``line``), else the line."""
    if isinstance(route, bool) or not isinstance(route, (int, float)) or route < 0:
        raise SimulationError(f"route: must be a length >= 0 (m) or NaN, got {route!r}")
    return line if np.isnan(route) else max(line, float(route))


def detour_reason(
    positions: np.ndarray,
    final_time: float,
    p0: np.ndarray,
    goal: np.ndarray,
    max_speed: float,
    route: float = float("nan"),
) -> str | None:
    """Why a replan is too long a detour to fly (see DETOUR_FACTOR), or None.

    positions : (K, 3) the plan's node positions; final_time : its duration (s); p0 : (3,) where
    the robot is; goal : (3,) where the plan goes; max_speed : the vehicle's top speed (m/s);
    route : the length (m) of the route through the robot's map the planner started from
    (:attr:`~secure3d.planning.result.PlanResult.route_length`), NaN if unknown. The detour is
    measured against that route, or the straight line when unknown: a goal 1.6 m away behind a
    wall may be 12 m away round it (a dead end), and a plan going round is no detour.
    """
    line = float(np.linalg.norm(np.asarray(goal, dtype=float) - p0))
    ref = _detour_reference(line, route)
    what = f"{line:.1f} m to the goal" if ref == line else f"a {ref:.1f} m route to the goal"
    length = float(np.linalg.norm(np.diff(positions, axis=0), axis=1).sum())
    if length > DETOUR_FACTOR * ref + DETOUR_SLACK_M:
        return f"replan refused: path {length:.1f} m for {what}"
    top = detour_time_limit(ref, max_speed)
    if final_time > top:
        return f"replan refused: {final_time:.1f} s for {what} (at most {top:.1f} s)"
    return None


def slow_replan_reason(final_time: float, stop_time: float, time_left: float) -> str | None:
    """Why a moving robot's replan is slower to fly than braking and planning from rest (see
    SLOW_REPLAN_FACTOR), or None. ``final_time``: the replan's duration (s); ``stop_time``: the
    braking manoeuvre's from the replan's start (s); ``time_left``: what the replaced plan had left."""
    for name, value in (
        ("final_time", final_time),
        ("stop_time", stop_time),
        ("time_left", time_left),
    ):
        if not np.isfinite(value) or (name != "time_left" and value < 0.0):
            raise SimulationError(
                f"slow_replan_reason: {name} must be a finite time (s), got {value!r}"
            )
    left = max(time_left, 0.0)  # a plan past its end has nothing left
    top = slow_replan_limit(stop_time, left)
    if final_time > top:
        return (
            f"replan refused: {final_time:.1f} s in flight, against {stop_time:.1f} s of braking "
            f"and {left:.1f} s left on the old plan (at most {top:.1f} s)"
        )
    return None


def goal_edge(
    position: np.ndarray, goal: np.ndarray, tolerance: float, reach: float
) -> np.ndarray | None:
    """Where to aim instead of the goal from a robot at rest at ``position`` (3,): the point
    ``GOAL_EDGE_FRACTION * tolerance`` from ``goal`` (3,) towards the robot, or None when the robot
    is within ``tolerance`` already or farther than ``tolerance + reach`` from the goal.

    Arrival counts anywhere within the tolerance, but plans end at their goal point. A robot that
    braked just short of the goal, because an obstacle it had just seen hid the goal's far side
    from every view, could not plan to the goal point (its reactive set reaches into space no view
    covers, and a view of it needs the robot to back off and turn), while the near side of the
    goal's ball lay in the region it had observed (``reach``: the start region's half size).
    """
    p, g = np.asarray(position, dtype=float), np.asarray(goal, dtype=float)
    if (
        p.shape != (3,)
        or g.shape != (3,)
        or not (np.all(np.isfinite(p)) and np.all(np.isfinite(g)))
    ):
        raise SimulationError(
            f"goal_edge: position and goal must be 3 finite numbers, got {p!r}, {g!r}"
        )
    if not (np.isfinite(tolerance) and tolerance > 0 and np.isfinite(reach) and reach >= 0):
        raise SimulationError(
            f"goal_edge: tolerance must be > 0 and reach >= 0 (m), got {tolerance!r}, {reach!r}"
        )
    d = float(np.linalg.norm(p - g))
    if d <= tolerance or d > tolerance + reach:
        return None
    return g + GOAL_EDGE_FRACTION * tolerance * (p - g) / d
