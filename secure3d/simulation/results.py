"""What a closed-loop run reports: :class:`SimResult` and its :class:`SimEvent` log."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from secure3d.planning.result import finite_or_none
from secure3d.simulation.modes import log

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.result import PlanResult
    from secure3d.simulation.flight import Flight
    from secure3d.simulation.modes import RunSettings

__all__ = ["SimEvent", "SimResult", "flight_result", "log_heartbeat"]


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
    plan_iterations : the solver's iterations in every plan call (all its solves), in the order of
        ``solve_times``: unlike the wall times, the same on every machine for the same code.
    certify_log : per plan call whose solver succeeded (secure planner): (how many solutions the
        certificate rejected first, whether the returned plan certified). (0, True): first try.
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
    certify_log: tuple[tuple[int, bool], ...] = ()
    plan_iterations: tuple[int, ...] = ()
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
            "plan_iterations": [int(i) for i in self.plan_iterations],
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


def flight_result(flight: Flight) -> SimResult:
    """The record of a finished (or stopped) :class:`~secure3d.simulation.flight.Flight`: its
    logs, counts and outcome, and the wall time since the run started."""
    model = flight.model
    states = np.array(flight.X_log)
    positions = np.asarray(model.position(states), dtype=float)
    speeds = np.linalg.norm(np.asarray(model.velocity(states), dtype=float), axis=1)
    return SimResult(
        scenario=flight.loop.scenario.name,
        planner=flight.loop.planner,
        seed=flight.s.seed,
        collided=flight.collided,
        collision_time=flight.collision_time,
        collision_obstacles=tuple(flight.collision_names),
        reached_goal=flight.reached,
        time_to_goal=flight.time_to_goal,
        min_clearance=flight.min_clear,
        times=np.array(flight.T_log),
        states=states,
        positions=positions,
        speeds=speeds,
        events=tuple(flight.events),
        plans=tuple(flight.plans),
        detection_time=flight.detection_time,
        detection_point=flight.detection_point,
        frames=flight.frame_no + 1,
        takeovers=flight.takeovers,
        replans=flight.replans,
        solve_times=tuple(flight.solve_times),
        plan_iterations=tuple(flight.plan_iterations),
        certify_log=tuple(flight.certify_log),
        wall_time=time.perf_counter() - flight.s.wall0,
    )


def log_heartbeat(name: str, t: float, settings: RunSettings, now: float, plans: int) -> None:
    """The INFO line a long flight logs every ``HEARTBEAT_SECONDS`` of wall time (``now``)."""
    log.info(
        "%s: %.2f of at most %.1f s flown in %.0f s of wall time, %d plans so far",
        name,
        t,
        settings.time_limit,
        now - settings.wall0,
        plans,
    )
