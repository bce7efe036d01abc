"""What the closed loop does at rest besides replanning: turn to face away from a known obstacle
the body rests beside, aim at the near side of the goal's ball, and back off a known obstacle the
body overlaps (the ``RETREAT`` mode, :mod:`secure3d.simulation.retreat`), and find where to
look at a goal no view has covered from. A mixin of
:class:`secure3d.simulation.flight.Flight`, whose state these methods read and change.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

from secure3d.simulation.loop import heading_error, scan_control
from secure3d.simulation.modes import (
    MAX_RETREATS,
    STOP_SPEED,
    STUCK_RETRIES,
    Trigger,
    goal_edge,
)

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.result import PlanResult

#: A retreat starts only from a robot slower than this (m/s): the body it backs off from is the
#: one at rest, and a robot still creeping towards the obstacle would leave it first.
RETREAT_START_SPEED = 0.005
#: Heading error (rad) to which a wheeled robot turns, and stops spinning (turn rate below
#: RETREAT_START_SPEED), before it drives along a retreat's line. The line may graze a voxel nobody
#: saw free: a diff drive that set off still turning at 0.7 rad/s, 0.13 rad off the line, swung its
#: body towards one at its first step, and the step's check stopped it (a real scan's dead end).
RETREAT_HEADING = 0.005
#: Seconds a wheeled robot may take to turn before a retreat (a half turn takes about 2 s).
RETREAT_TURN_TIME = 10.0


class AtRest:
    """At-rest behaviours of :class:`~secure3d.simulation.flight.Flight` (see the module)."""

    def face_away(self) -> float | None:
        """At rest: the heading to turn to before replanning (:meth:`Loop.way_off`), or None."""
        heading = self.loop.way_off(self.model, self.x)
        if heading is not None:
            self.event(
                "face away",
                f"at rest within {1e3 * self.loop.problem.options.margin:.0f} mm of a known"
                f" obstacle: turning to {np.degrees(heading):.0f} deg before replanning",
            )
        return heading

    def plan_to_goal_edge(self) -> PlanResult | None:
        """At rest near the goal (within the start region's half size of its tolerance ball), plan
        to the near side of that ball (:func:`~secure3d.simulation.modes.goal_edge`) rather than
        to the goal point; None when farther or when that plan fails."""
        p = np.asarray(self.model.position(self.x), dtype=float).ravel()
        reach = self.loop.problem.options.start_region_radius
        if (edge := goal_edge(p, self.s.goal, self.loop.scenario.goal.tolerance, reach)) is None:
            return None
        self.event("aim nearer", f"to {np.round(edge, 2).tolist()}, inside the goal tolerance")
        return self.make_plan(self.x, goal=edge)

    def goal_view(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(point to look from, the goal) when STUCK_RETRIES replans at rest have failed within the
        camera's range of the goal and no view has covered the goal's surroundings
        (:func:`~secure3d.simulation.explore.viewpoint_for_goal`), else None."""
        from secure3d.simulation.explore import viewpoint_for_goal

        problem, goal = self.loop.start_problem, np.asarray(self.s.goal, dtype=float)
        p = np.asarray(self.model.position(self.x), dtype=float).ravel()
        near = float(np.linalg.norm(p - goal)) <= problem.frustum.far
        if self.held_failures < STUCK_RETRIES or not near:
            return None
        view = viewpoint_for_goal(problem, self.loop.belief, p, goal)
        return None if view is None else (view, goal)

    def start_retreat(self) -> bool:
        """HOLD -> RETREAT when the body at rest overlaps a known obstacle (the planner would refuse
        the start), or rests within the planner's margin of one after STUCK_RETRIES failed replans,
        and a straight retreat off it is found (:meth:`Loop.retreat_from`)."""
        if self.retreats >= MAX_RETREATS:
            return False
        if float(np.linalg.norm(self.model.velocity(self.x))) > RETREAT_START_SPEED:
            return False
        stuck = self.held_failures >= STUCK_RETRIES
        retreat = self.loop.retreat_from(self.x, self.t, in_margin=stuck)
        if retreat is None:
            return False
        self.retreats += 1
        self.retreat = retreat
        to = np.round(retreat.end, 3).tolist()
        self.event(
            "retreat",
            f"at rest, the body {'is within the margin of' if stuck else 'overlaps'} a known"
            f" obstacle: backing off {1e3 * retreat.length:.0f} mm to {to} before replanning",
            "WARN",
        )
        self.go(Trigger.OVERLAPS)
        return True

    def act_retreat(self) -> np.ndarray:
        """Follow the retreat; once it has ended, HOLD (and replan). If a step would take the body
        where the retreat's check refuses, brake instead (RETREAT -> BRAKE)."""
        rt, loop = self.retreat, self.loop
        if rt.turn:  # a wheeled robot turns on the spot to face along the line first
            err = heading_error(rt.yaw, float(self.model.yaw(self.x)))
            spin = np.abs(np.asarray(self.model.rest_residuals(self.x), dtype=float))
            if abs(err) >= RETREAT_HEADING or np.any(spin > RETREAT_START_SPEED):
                if self.t - rt.start <= RETREAT_TURN_TIME:
                    return scan_control(self.model, loop.brake, self.x, rt.yaw, self.s.dt)
                return self.stop_retreat(f"the turn did not settle in {RETREAT_TURN_TIME:.0f} s")
            self.retreat = rt = dataclasses.replace(rt, start=self.t, turn=False)
        if rt.done(self.model, self.x, self.t, STOP_SPEED):
            p = np.asarray(self.model.position(self.x), dtype=float).ravel()
            moved = 1e3 * float(np.linalg.norm(p - rt.anchor))
            self.event("backed off", f"{moved:.0f} mm, to {np.round(p, 3).tolist()}")
            self.retreat = None
            self.go(Trigger.BACKED_OFF)
            self.last_attempt = -np.inf
            self.held_failures = 0  # a new start: the replans from there count afresh
            return self.act_hold()
        u, why = rt.control(self.model, loop.tracker, loop.brake, self.x, self.t, self.s.dt)
        return u if why is None else self.stop_retreat(why)

    def stop_retreat(self, why: str) -> np.ndarray:
        """Give the retreat up and brake (RETREAT -> BRAKE): the control for this step."""
        self.event("retreat stopped", f"{why}: braking", "WARN")
        self.retreat = None
        self.go(Trigger.UNSAFE)
        return self.act_brake()
