"""The paper's Algorithm 1 in closed loop, against the true world (:func:`secure3d.simulate` adds
the run's files: a Rerun recording and a figure, :mod:`secure3d.session`).

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
The loop itself is the state machine of :mod:`secure3d.simulation.flight` (modes and transitions in
one table, matched to Algorithm 1 line by line); the run's state is
:class:`~secure3d.simulation.loop.Loop`; the report is :class:`SimResult`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from secure3d._kernel_manifest import loaded_signatures as loaded_kernels
from secure3d._kernel_manifest import record as record_kernels
from secure3d.errors import SimulationError
from secure3d.planning.problem import Planner
from secure3d.simulation.flight import Flight
from secure3d.simulation.guard import TrackingGuard
from secure3d.simulation.loop import (
    CERT_STEP,
    CLOSED_LOOP_MAX_ITER,
    CLOSED_LOOP_NODES,
    CLOSED_LOOP_OBSTACLE_SLOTS,
    SCAN_RATE_FRACTION,
    SCAN_TOLERANCE,
    Loop,
    observed_box,
    scan_headings,
)
from secure3d.simulation.modes import (
    ARRIVAL_SPEED,
    CONTACT_SAMPLES,
    HEARTBEAT_SECONDS,
    REPLAN_RETRY,
    RETRY_SPEEDS,
    STOP_SPEED,
    STUCK_RETRIES,
    SURFACE_BIAS,
    Mode,
    RunSettings,
    Trigger,
)
from secure3d.simulation.recording import NULL_RECORDER, Recorder
from secure3d.simulation.results import SimEvent, SimResult
from secure3d.validation import is_real

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.world.spec import Scenario

__all__ = [
    "ARRIVAL_SPEED",
    "CERT_STEP",
    "CLOSED_LOOP_MAX_ITER",
    "CLOSED_LOOP_NODES",
    "CLOSED_LOOP_OBSTACLE_SLOTS",
    "CONTACT_SAMPLES",
    "DEFAULT_REPLAN_DEFER",
    "HEARTBEAT_SECONDS",
    "REPLAN_RETRY",
    "RETRY_SPEEDS",
    "SCAN_RATE_FRACTION",
    "SCAN_TOLERANCE",
    "STOP_SPEED",
    "STUCK_RETRIES",
    "SURFACE_BIAS",
    "Mode",
    "SimEvent",
    "SimResult",
    "Trigger",
    "check_replan_seconds",
    "observed_box",
    "replan_defer_for",
    "scan_headings",
    "simulate",
]

#: Default ``replan_defer`` of :func:`simulate` (s). Measured on the 200 hidden-obstacle variants of
#: the blind corner: see ``benchmarks/results/campaign_blind_corner.md``.
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
    if not is_real(value) or not 0.0 <= value < 10.0:
        raise error(f"{name}: seconds in [0, 10), got {value!r}")
    return float(value)


def simulate(
    scenario: Scenario | str | Path,
    planner: str = "secure",
    seed: int = 0,
    *,
    recorder: Recorder | None = None,
    cache: object | None = None,
    max_replans: int = 25,
    look_around: bool = False,
    tracking_guard: bool = True,
    explore: bool = True,
    tracker: object | None = None,
    disturbance: Callable[[float, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    | None = None,
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
    recorder : where the run is logged as it happens (default: nowhere); aborted here if the
        flight raises, else closed by the caller. :func:`secure3d.simulate` opens a Rerun recording here for ``rrd=`` and draws the
        figure of ``png=`` from the result: the simulator itself writes no files.
    cache : an :class:`~secure3d.planning.collocation.NLPCache` for the compiled NLPs (default: the
        planner's module-wide cache, so runs in one process build each NLP shape once).
    max_replans : give up (robot holds still) after this many failed or successful replans, or
        after ``2 * STUCK_RETRIES`` failed ones in a row at rest.
    replan_in_flight, replan_latency, replan_defer : when new evidence breaks the rest of the plan:
        replan from the moving state before braking; the simulated seconds a replan takes
        (default 0); how long before the plan's first failing manoeuvre to replan (s; default
        None: :data:`DEFAULT_REPLAN_DEFER`, 0.5, or 0 with a ``replan_latency``; 0: at once).
        These and the next are described in full at :class:`~secure3d.simulation.modes.RunSettings`.
    look_around : turn the camera at rest before replanning after a take-over or a failed replan.
    frame_log_every, belief_log_every : decimation of camera frames and belief voxels in the recording.
    tracking_guard : secure planner only: check that the real state stays in the certified tube
        and brake at once when it leaves it (:mod:`secure3d.simulation.guard`).
    explore : when the map shows no route because of claims the camera has not checked, fly
        certified plans to look at the claim that blocks the shortest route
        (:mod:`secure3d.simulation.explore`) instead of holding.
    tracker : the plan-following controller, an object with ``control(x, x_ref, u_ref) -> u``
        (default :func:`~secure3d.simulation.tracking.make_tracker` for the vehicle); a seam for
        studies of tracker faults.
    disturbance : ``(t, x, u) -> (x, u)``, applied before every integration step: a gust (change
        ``x``) or a tracker or actuator fault (change ``u``), for robustness studies and tests.
    **options : planner options (see :class:`~secure3d.planning.problem.PlannerOptions`).
    """
    scenario = _as_scenario(scenario)
    if planner not in tuple(Planner):
        raise SimulationError(f"planner: must be 'secure' or 'baseline', got {planner!r}")
    replan_latency = check_replan_seconds("replan_latency", replan_latency)
    replan_defer = replan_defer_for(replan_defer, replan_latency)
    wall0 = time.perf_counter()
    loop = Loop(scenario, planner, seed, dict(options), cache)
    settings = _run_settings(
        scenario,
        max_replans=max_replans,
        look_around=look_around,
        replan_in_flight=replan_in_flight,
        replan_latency=replan_latency,
        replan_defer=replan_defer,
        frame_log_every=frame_log_every,
        belief_log_every=belief_log_every,
        seed=seed,
        wall0=wall0,
        disturbance=disturbance,
        explore=explore,
    )
    setup_time = time.perf_counter() - wall0  # take-off: the NLP compiled
    guarded = tracking_guard and planner == Planner.SECURE
    result = _fly(loop, NULL_RECORDER if recorder is None else recorder, settings, tracker, guarded)
    return dataclasses.replace(result, setup_time=setup_time)


def _as_scenario(scenario: Scenario | str | Path) -> Scenario:
    """``scenario``, loaded if it is the path of a scenario YAML file."""
    if isinstance(scenario, (str, Path)):
        from secure3d.world.scenario import load_scenario

        return load_scenario(scenario)
    return scenario


def _run_settings(scenario: Scenario, **flags: object) -> RunSettings:
    """:func:`simulate`'s settings: the scenario's step, frame period, goal and time limit, and
    the run's ``flags`` (the other fields of :class:`RunSettings`)."""
    return RunSettings(
        dt=scenario.simulation.dt,
        frame_period=1.0 / scenario.camera.rate_hz,
        goal=np.asarray(scenario.goal.position, dtype=float),
        time_limit=scenario.simulation.time_limit,
        **flags,
    )


def _fly(
    loop: Loop, recorder: Recorder, settings: RunSettings, tracker: object | None, guarded: bool
) -> SimResult:
    """Fly the loop (with ``tracker`` instead of the vehicle's, and the tracking guard if
    ``guarded``); the recording is aborted if the flight raises. The kernels the flight called
    first go to the manifest the next set-up preloads (:mod:`secure3d._kernel_manifest`)."""
    try:
        if tracker is not None:
            loop.tracker = tracker
        guard = TrackingGuard(loop) if guarded else None
        loaded = loaded_kernels()
        result = Flight(loop, recorder, settings, guard).run()
        record_kernels(since=loaded)  # what the flight first called, for the next set-up's preload
        return result
    except BaseException:
        recorder.abort()
        raise
