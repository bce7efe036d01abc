"""Obstacle-slot refreshes: re-solving a solution whose slots left out a box it came near.

The NLP's obstacles are parameters, a fixed number of slots per node chosen near the iterate
(:func:`~secure3d.planning.lookback.select_slots`); on the solution other boxes may have come
closer. :func:`refresh_slots` re-selects the slots on the solution and re-solves, warm from it
(:func:`resolve_from`), while a box left out comes too close; a re-solve that runs away from the
solution is stopped and, where the call allows it, replaced by a solve from the round's own start
(:func:`restart_from`); in a plan from rest, a re-solve that ends without a solution leaves the
solution it refreshed to the certificate (:data:`KEEP_STALE`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from secure3d.errors import PlanningError
from secure3d.planning import lookback as lb
from secure3d.planning.interrupt import budget_spent, final_time_watch, ran_away
from secure3d.planning.nlp_cache import NLPCache
from secure3d.planning.nlp_solve import SolveCost, _Solve, _solve_once
from secure3d.planning.problem import PlanningProblem
from secure3d.planning.result import Certificate

__all__ = [
    "KEEP_STALE",
    "REFRESH_RUNAWAY",
    "SLOT_REFRESHES",
    "refresh_slots",
    "resolve_from",
    "restart_from",
]

log = logging.getLogger(__name__)

#: Re-selections of the obstacle slots on a solution before it is accepted.
SLOT_REFRESHES = 3

#: A refresh whose re-solve ends without a solution, in a call that tries slower guesses (a plan
#: from rest, whose alternative is failing and holding still), keeps the solution it refreshed:
#: optimal for an NLP that left a box out (a relaxation), so not proven optimal, but the
#: certificate judges every box, and a plan it certifies is as safe as any other. Without this,
#: such a call threw that solution away and, near the many small boxes of a scan or of a robot
#: braked beside a wall, spent its whole budget on refreshes that ran away one after another
#: (holdout seed 4001, geb079_region_attacks corner variant 2: eight plan calls at rest of ~8.5 s
#: each, every one with a solution in hand; benchmarks/results/session40.md). A moving robot's
#: replan still fails there and brakes: keeping its stale solution too, the 200-run forest
#: campaign arrived 2.5-3.4 s later in three runs (the certificate refused the stale plans, and
#: their tightened re-solves were slower than braking and planning from rest) and sooner in one.
KEEP_STALE = True

#: A slot refresh re-solves from the solution it refreshes, which may pass through boxes its slots
#: left out. That is a good start when the new rows only nudge it, but from a solution that runs
#: through a wall of survey stripes the solve can win feasibility back only by slowing down
#: (warehouse_survey, occlusion3d variant 3 of seed 3601: T 5.2 -> 15 s over 160 iterations, into
#: the plan's budget, on every one of its replans). Such a re-solve is stopped once its final time
#: passes this many times the solution's, and the refresh solves once from the round's own start
#: (the guess) instead, with the refreshed slots; a call that tries no slower guesses (a replan of
#: a moving robot, which brakes instead) fails there.
REFRESH_RUNAWAY = 1.5


def _tightened_margin(problem: PlanningProblem, extra_margin: float | np.ndarray) -> float:
    """The planner's margin plus the largest of ``extra_margin`` (m): how near a left-out box may
    come to what a node constrains before a re-solve puts it in the node's slots."""
    return problem.options.margin + float(np.max(extra_margin))


def resolve_from(
    problem: PlanningProblem,
    planner: str,
    s: _Solve,
    cache: NLPCache,
    multipliers: tuple | None,
    extra_margin: float | np.ndarray,
) -> _Solve:
    """Solve again from solution ``s`` (its assignment, primal point, duals, slots and grid), with
    the margin rows tightened by ``extra_margin``, warm from ``multipliers`` if given; the slots
    re-selected on ``s`` also take every box that comes within the tightened margin of it."""
    return _solve_once(
        problem,
        planner,
        s.assignment,
        s.T,
        s.X,
        s.U,
        cache,
        L=s.L,
        multipliers=multipliers,
        prev_slots=s.slots,
        extra_margin=extra_margin,
        grid=s.grid,
        left_out_limit=_tightened_margin(problem, extra_margin),
    )


def restart_from(
    problem: PlanningProblem,
    planner: str,
    s: _Solve,
    start: tuple[float, np.ndarray, np.ndarray, np.ndarray | None],
    cache: NLPCache,
    extra_margin: float | np.ndarray,
) -> _Solve:
    """Solve from ``start`` (T, X, U, grid), cold, with the slots of solution ``s`` and every box
    that comes within the (tightened) margin of it put in
    (:func:`~secure3d.planning.lookback.with_left_out_boxes`)."""
    limit = _tightened_margin(problem, extra_margin)
    slots = lb.with_left_out_boxes(problem, s.X, s.assignment, s.slots, limit)
    T, X, U, grid = start
    return _solve_once(
        problem,
        planner,
        s.assignment,
        T,
        X,
        U,
        cache,
        extra_margin=extra_margin,
        grid=grid,
        slots=slots,
    )


def refresh_slots(
    problem: PlanningProblem,
    planner: str,
    s: _Solve,
    cache: NLPCache,
    extra_margin: float | np.ndarray = 0.0,
    start: tuple[float, np.ndarray, np.ndarray, np.ndarray | None] | None = None,
    accept: Callable[[_Solve], Certificate | None] | None = None,
) -> tuple[_Solve, SolveCost]:
    """Re-select the obstacle slots on solution ``s`` and re-solve warm, up to SLOT_REFRESHES
    times, while :func:`~secure3d.planning.lookback.slots_stale` (a box left out of them comes
    closer than part of the margin). Returns the last solution, and what the re-solves cost.
    ``accept``: asked once, of ``s`` if its slots are stale, before the first re-solve; a
    certificate it returns ends the refresh with ``s`` and that certificate (no re-solve).
    ``extra_margin``: one margin (m), or one per node, added to the re-solves' margin rows.
    ``start``: the (T, X, U, grid) the solve of ``s`` started from, if the re-solves are watched:
    one whose final time runs past REFRESH_RUNAWAY times its solution's is stopped
    (``ITERATION_LIMIT``) and, if the call tries slower guesses (``slower_guesses``; a moving
    robot's replan does not: it brakes instead, and from a moving start the restart found the same
    slow plan), replaced once by a solve from ``start`` (:func:`restart_from`).

    In a call that tries slower guesses, a re-solve that ends without a solution (stopped,
    iteration limit, infeasible) hands back the solution it refreshed, its slots stale, for the
    certificate to judge (:data:`KEEP_STALE`).

    Obstacles are NLP parameters chosen near the iterate; on the solution other boxes may have come
    closer. With the slots the NLP is a relaxation of the NLP with every box, so a solution no
    left-out box comes within the margin of is feasible, hence (locally) optimal, for it too; and
    one no left-out box comes within ``(1 - lookback.SLOT_TOLERANCE)`` of the margin of is so for
    the NLP whose rows for those boxes keep that part of the margin (the certificate judges every
    box either way). (A slack of 0.05 m cost a second solve on blind_corner: cold 0.47 s / 51
    iterations -> 0.31 s / 33 without; 8 hidden-obstacle flights: 0.63x -> 0.68x real time, same
    outcomes.) The certificate's tightened re-solves (``extra_margin``) go through here too:
    without it a tightened solution moved onto boxes outside its slots (issue 16: obstacle
    margins down to -0.8 m).
    """
    if accept is not None and not callable(accept):
        raise PlanningError(f"refresh_slots: accept must be callable or None, got {accept!r}")
    cost = SolveCost()
    restarted = False
    keep = KEEP_STALE and problem.options.slower_guesses
    for i in range(SLOT_REFRESHES):
        if (
            not s.status.ok
            or budget_spent()
            or not lb.slots_stale(problem, planner, s.X, s.assignment, s.slots)
        ):
            break
        cert = accept(s) if i == 0 and accept is not None else None
        if cert is not None:
            return replace(s, certificate=cert), cost
        watch = start is not None and (keep or not restarted)
        with final_time_watch(REFRESH_RUNAWAY * s.T if watch else np.inf):
            r = resolve_from(problem, planner, s, cache, None, extra_margin)
        cost = cost + SolveCost(0.0, r.solve_time, r.iterations)
        restart = start is not None and not restarted and problem.options.slower_guesses
        if restart and ran_away() and not budget_spent():
            r = restart_from(problem, planner, s, start, cache, extra_margin)
            cost = cost + SolveCost(0.0, r.solve_time, r.iterations)
            restarted = True
        if keep and not r.status.ok:
            log.debug(
                "slot refresh: re-solve ended %s (%s); keeping the solution it refreshed",
                r.status.name,
                r.message,
            )
            return s, cost
        s = r
    return s, cost
