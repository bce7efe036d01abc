"""``secure3d.plan``: the secure minimum-time planner and its baseline.

Pipeline (each step a function, the problem itself in :mod:`.problem`):

1. guess: graph search on the belief map, time-scaled (:mod:`.guess`), or the rest of a previous
   plan (warm replan, primal and multipliers);
2. look-back assignment: the paper's fixed Δi or the adaptive rule (:mod:`.lookback`);
3. obstacle slots: nearest known boxes per node, as NLP parameters;
4. solve the NLP (:mod:`.nlp_solve`; built by a transcription of :mod:`.nlp_cache`, compiled once
   per structure and cached);
5. adaptive rule only: re-assign on the solution and re-solve warm until stable;
6. certify the result independently (:mod:`.certificate`); a plan that does not certify is reported
   as ``NOT_CERTIFIED``, never as success.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from secure3d.errors import ConfigError
from secure3d.planning import lookback as lb
from secure3d.planning.blas import pin_blas_threads
from secure3d.planning.guess import (
    Guess,
    NoPathError,
    guess_along_plan,
    guess_from_plan,
    initial_guess,
)
from secure3d.planning.interrupt import budget_spent, deadline
from secure3d.planning.judging import (  # noqa: F401  (the constants: re-exported)
    CERTIFY_STALE,
    CERTIFY_TIGHTENING,
    START_TIGHTENING,
)
from secure3d.planning.judging import judged as _judged
from secure3d.planning.judging import refreshed as _refreshed
from secure3d.planning.nlp_cache import NLPCache
from secure3d.planning.nlp_solve import (  # noqa: F401  (the constants: re-exported)
    FEASIBILITY_TOL,
    MARGIN_FAMILIES,
    T_GUESS_FACTOR,
    SolveCost,
    _Solve,
    _solve_once,
)
from secure3d.planning.outcome import failed_result, precheck, solution_result
from secure3d.planning.problem import Planner, PlanningProblem, problem_from_scenario
from secure3d.planning.result import PlanResult, PlanStatus
from secure3d.planning.slot_refresh import (  # noqa: F401  (the constants: re-exported)
    REFRESH_RUNAWAY,
    SLOT_REFRESHES,
)

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.mapping.occupancy import OccupancyMap
    from secure3d.world.spec import Scenario

#: Shared by ``plan`` and ``simulate`` calls that do not pass their own cache. A compiled NLP holds
#: 60-80 MB (blind_corner, K=40, 8-12 obstacle slots), so the shared cache keeps only the 8 most
#: recently used.
DEFAULT_CACHE = NLPCache(max_size=8)

#: Part of a plan call's budget kept back for what follows the last solve (reading the solution,
#: the result): solves stop at the budget minus this much (at most BUDGET_RESERVE_MAX s). In
#: campaigns with a 10 s budget, calls that hit it overran it by 0.03-0.1 s (median) without it.
BUDGET_RESERVE = 0.05
BUDGET_RESERVE_MAX = 0.5

#: Part of a secure plan call's budget its solves leave to the certificate (at most
#: CERTIFY_RESERVE_MAX s): certifying a plan takes 0.1-1.4 s (a 37 s quadrotor plan: 30,000
#: manoeuvre points). A certificate that still finds the budget spent stops (``TIME_BUDGET``).
CERTIFY_RESERVE = 0.1
CERTIFY_RESERVE_MAX = 1.5


def _first_round(
    problem: PlanningProblem,
    planner: str,
    guess: Guess,
    warm: PlanResult | None,
    dual_start: bool,
    near_fraction: float | None = None,
) -> tuple[tuple[int, ...], tuple | None, np.ndarray | None, np.ndarray | None]:
    """The first round's look-back assignment (``near_fraction``: see
    :func:`~secure3d.planning.lookback.adaptive_assignment`), and from a warm plan its multipliers
    (with ``dual_start``), obstacle duals and slots: ``(assignment, multipliers, L, slots)``."""
    o = problem.options
    K = o.nodes
    if planner == Planner.BASELINE:
        assignment: tuple[int, ...] = (-1,) * K
    elif o.lookback == "fixed":
        assignment = lb.fixed_assignment(K, o.lookback_steps)
    else:
        assignment, _ = lb.adaptive_assignment(problem, guess.states, near_fraction)
    multipliers = None
    L0 = None
    prev_slots = None
    if warm is not None and warm.warm is not None:
        # Same structure as the previous plan: its multipliers are a good start even after the
        # remaining trajectory was resampled from warm_time on (node i keeps its role).
        if dual_start:
            multipliers = (warm.warm.key, warm.warm.lam_x, warm.warm.lam_g)
        L0 = warm.warm.L
        prev_slots = warm.warm.slots
        if planner == Planner.SECURE and o.lookback == "adaptive":
            assignment = tuple(warm.warm.assignment)
    return assignment, multipliers, L0, prev_slots


def _solve_rounds(
    problem: PlanningProblem,
    planner: str,
    guess: Guess,
    warm: PlanResult | None,
    warm_time: float,
    cache: NLPCache,
    dual_start: bool = True,
    max_final_time: float = np.inf,
    near_fraction: float | None = None,
) -> tuple[_Solve, SolveCost]:
    """Assign look-backs on the guess, solve, and (adaptive rule) re-assign and re-solve. A warm
    replan starts from the previous plan's multipliers too, with the warm-start solver, unless
    ``dual_start`` is False (then the cold solver's barrier schedule from the primal guess). A
    solution longer than ``max_final_time`` is returned at once (no slot refresh, no round)."""
    o = problem.options
    assignment, multipliers, L0, prev_slots = _first_round(
        problem, planner, guess, warm, dual_start, near_fraction
    )
    cost = SolveCost()
    T, X, U = guess.final_time, guess.states, guess.controls
    grid = guess.times / guess.final_time if warm is not None else None
    rounds = o.lookback_rounds if (planner == Planner.SECURE and o.lookback == "adaptive") else 1
    if warm is not None:
        rounds = 1  # a warm replan keeps the previous, already refined, assignment
    best: _Solve | None = None
    for _ in range(rounds):
        n_before = cache.misses
        s = _solve_once(
            problem,
            planner,
            assignment,
            T,
            X,
            U,
            cache,
            L=L0,
            multipliers=multipliers,
            prev_slots=prev_slots,
            grid=grid,
        )
        built = s.nlp.build_time if cache.misses > n_before else 0.0
        cost = cost + SolveCost(built + s.warm_build, s.solve_time, s.iterations)
        if s.status.ok and s.T > max_final_time:
            return s, cost
        s, c = _refreshed(problem, planner, s, cache, start=(T, X, U, grid))
        cost = cost + c
        if best is None or (s.status.ok and (not best.status.ok or s.T < best.T)):
            best = s
        if not s.status.ok or rounds == 1 or budget_spent():
            break
        new_assignment = lb.refine_assignment(problem, s.X, assignment)
        if new_assignment == assignment:
            break
        assignment = new_assignment
        T, X, U, L0, multipliers, prev_slots = s.T, s.X, s.U, s.L, None, s.slots
        grid = s.grid
    return best, cost


#: Cruise speeds of the slower guesses a cold plan falls back to, in turn, when the solve from the
#: first guess fails (fractions of the first guess's: ``guess_speed_fraction`` for the secure
#: planner, the speed limit for the baseline). The third start came with
#: the assembled derivatives: planar_blind_corner (diff drive) failed from 1.0 and 0.5 (solver error
#: after 24 iterations, iteration limit) and solves from 0.3 in 28 iterations. The diff-drive NLPs
#: are this fragile either way: with CasADi's own derivatives a 1e-9 relative change of the guess
#: took the same solve from 25 to 471 iterations.
RETRY_GUESS_SPEEDS = (0.5, 0.3)


def plan_problem(
    problem: PlanningProblem,
    planner: str = "secure",
    *,
    warm: PlanResult | None = None,
    warm_time: float = 0.0,
    cache: NLPCache | None = None,
    solve_rounds: Callable[..., tuple[_Solve, SolveCost]] | None = None,
    max_final_time: float = np.inf,
    route_time_limit: Callable[[float], float] | None = None,
) -> PlanResult:
    """Solve a :class:`PlanningProblem` (see :func:`plan` for the scenario-level entry point).

    The whole call, every retry included, runs within ``problem.options.plan_budget`` seconds of
    wall time (status ``TIME_BUDGET`` when it ran out).

    Parameters
    ----------
    problem : the problem in the robot's belief.
    planner : ``"secure"`` (eq. NLP with reactive-set visibility and obstacle constraints) or
        ``"baseline"`` (dynamics, limits and body-vs-known-obstacle avoidance only).
    warm : a previous plan to start from (its remainder after ``warm_time`` seconds).
    cache : compiled NLPs to reuse; default: a module-wide cache.
    solve_rounds : one solve from a guess with its look-back rounds (default the real one); a
        seam for tests that make solves fail.
    max_final_time : the longest plan (s) the caller would use (a closed loop's replan that must
        beat braking). A solution longer than that ends the call with status ``TOO_SLOW``, before
        its slot refreshes, look-back rounds and certificate: they would cost a solve or more
        each for a plan nobody flies.
    route_time_limit : the longest plan (s) the caller would use as a function of the length (m)
        of the route the call's first guess follows through the belief (the result's
        ``route_length``), for a cold call; it lowers ``max_final_time`` once that guess exists.
        A closed loop that refuses detours measured against that route passes its rule here, so
        a plan it would refuse ends the call as early as ``max_final_time`` would end it.
    """
    if planner not in tuple(Planner):
        raise ConfigError(f"planner: must be 'secure' or 'baseline', got {planner!r}")
    if not _is_time(max_final_time):
        raise ConfigError(f"max_final_time: must be a time > 0 (s), got {max_final_time!r}")
    if route_time_limit is not None and not callable(route_time_limit):
        raise ConfigError(
            f"route_time_limit: must be a function of the route length (m), got"
            f" {route_time_limit!r}"
        )
    cache = DEFAULT_CACHE if cache is None else cache
    pin_blas_threads()  # the same iterates whatever the machine's cores (planning/blas.py)
    budget = problem.options.plan_budget
    certifies = planner == Planner.SECURE and problem.options.certify
    reserve = min(CERTIFY_RESERVE * budget, CERTIFY_RESERVE_MAX) if certifies else 0.0
    with deadline(budget - min(BUDGET_RESERVE * budget, BUDGET_RESERVE_MAX), reserve):
        call = _Call(problem, planner, warm, warm_time, cache, solve_rounds or _solve_rounds)
        call = replace(call, max_final_time=max_final_time, route_time_limit=route_time_limit)
        return _plan_within_budget(call)


@dataclass(frozen=True)
class _Call:
    """What one plan call was given (see :func:`plan_problem`), as its steps read it."""

    problem: PlanningProblem
    planner: str
    warm: PlanResult | None
    warm_time: float
    cache: NLPCache
    solve_rounds: Callable[..., tuple[_Solve, SolveCost]]
    max_final_time: float = np.inf
    route_time_limit: Callable[[float], float] | None = None


def _plan_within_budget(call: _Call) -> PlanResult:
    problem, planner, warm, warm_time = call.problem, call.planner, call.warm, call.warm_time
    o = problem.options
    reason = precheck(problem)
    if reason is not None:
        return failed_result(problem, planner, PlanStatus.INVALID_INPUT, reason)
    from_other = None
    if warm is not None and warm.ok and warm.planner != planner and len(warm.times) >= 2:
        # The other planner's plan (e.g. the secure planner from the baseline's solution): its
        # path, time-scaled for this planner; then a cold solve (its duals, slots and look-back
        # belong to other constraints, and the baseline's speeds along a corner it cuts are no
        # start for the secure NLP: from them blind_corner ran into the iteration limit).
        from_other, warm = warm, None
    if (
        warm is not None
        and warm.ok
        and len(warm.times) == o.nodes
        and warm.model_name == problem.model.name
    ):
        guess = guess_from_plan(problem, warm, warm_time)
        # From the previous primal-dual solution first; if that fails, from its primal part
        # alone with the cold solver's barrier schedule. (The diff-drive's warm starts are
        # fragile: planar_passage_20cm ran to the 60 s limit from the multipliers and solves in
        # 1.4 s / 77 iterations without them; the point mass's are not: blind_corner 6
        # iterations with them, 17 without.)
        attempts: list[tuple[Guess | float, bool, float | None]] = [
            (guess, True, None),
            (guess, False, None),
        ]
    else:
        warm = None
        attempts = _cold_attempts(problem, planner, from_other, warm_time)
        if isinstance(attempts, str):
            return failed_result(problem, planner, PlanStatus.INFEASIBLE, attempts)
    if warm is not None:
        return _first_solved(call, attempts)
    # a cold plan: the route its first guess follows through the belief
    route = float(np.linalg.norm(np.diff(attempts[0][0].path, axis=0), axis=1).sum())
    call = replace(call, warm=None, max_final_time=_route_limited(call, route))
    return replace(_first_solved(call, attempts), route_length=route)


def _is_time(value: object) -> bool:
    """Whether ``value`` is a duration > 0 (s): a real number, not a bool, inf allowed."""
    return not isinstance(value, bool) and isinstance(value, (int, float)) and value > 0


def _route_limited(call: _Call, route: float) -> float:
    """The call's ``max_final_time``, lowered by its ``route_time_limit`` of ``route`` m."""
    if call.route_time_limit is None:
        return call.max_final_time
    limit = call.route_time_limit(route)
    if not _is_time(limit):
        raise ConfigError(
            f"route_time_limit: must return a time > 0 (s) for a route of {route:.3f} m, got"
            f" {limit!r}"
        )
    return min(call.max_final_time, float(limit))


def _first_solved(
    call: _Call, attempts: list[tuple[Guess | float, bool, float | None]]
) -> PlanResult:
    """Solve from the ``attempts`` in turn until one solves (within the budget), then judge that
    solution (TOO_SLOW over ``max_final_time``, else certified) and try the extra starts."""
    problem, planner, warm, cache = call.problem, call.planner, call.warm, call.cache
    solve_rounds, max_final_time = call.solve_rounds, call.max_final_time
    o = problem.options
    s = None
    cost = SolveCost()
    solved: list[tuple[Guess, bool, float | None]] = []  # the starts solved, in turn
    for g, dual_start, near in attempts:
        if s is not None and budget_spent():
            break
        if isinstance(g, float):
            g = initial_guess(problem, secure=planner == Planner.SECURE, speed_fraction=g)
        elif near is not None and not lb.near_views_differ(problem, g.states, near):
            continue  # the same views: the same failed solve
        if _solved_before(solved, g, dual_start, near):
            continue  # a slower guess capped to the same speeds: the same failed solve
        solved.append((g, dual_start, near))
        s, c = solve_rounds(
            problem,
            planner,
            g,
            warm,
            call.warm_time,
            cache,
            dual_start,
            max_final_time=max_final_time,
            near_fraction=near,
        )
        cost = cost + c
        if s.status.ok:
            break
    if s.status.ok and s.T > max_final_time:
        return _too_slow(problem, planner, s, max_final_time, cost)
    result = _judged(problem, planner, s, cost, cache, max_final_time)
    if warm is None and o.extra_starts:
        result = _extra_starts(problem, planner, result, cost, cache, solve_rounds, solved)
    return result


def _same_guess(a: Guess, b: Guess) -> bool:
    """Whether two guesses are the same start, bit for bit (then a solve from either ends alike:
    the solves are deterministic, planning/blas.py)."""
    return all(
        np.array_equal(getattr(a, f), getattr(b, f)) for f in ("times", "states", "controls")
    )


def _solved_before(
    solved: list[tuple[Guess, bool, float | None]], g: Guess, dual_start: bool, near: float | None
) -> bool:
    """Whether a start with guess ``g``, ``dual_start`` and near-view fraction ``near`` was solved
    already in this call. Guesses at different speed fractions coincide where the speed caps
    (visibility, the limits) bind all along: paper_passage_20cm's extra start at 1.0 is its first
    guess at 0.8, bit for bit, and re-solved it in 38 iterations to the same plan."""
    return any(d == dual_start and n == near and _same_guess(h, g) for h, d, n in solved)


def _cold_attempts(
    problem: PlanningProblem, planner: str, from_other: PlanResult | None, warm_time: float
) -> list[tuple[Guess | float, bool, float | None]] | str:
    """A cold plan's starts, in turn until one solves: (guess or a slower guess's speed fraction,
    dual start, near-view fraction); or why there is no guess (no path)."""
    o = problem.options
    try:
        if from_other is not None:
            guess = guess_along_plan(problem, planner, from_other, warm_time)
        else:
            guess = initial_guess(
                problem,
                secure=planner == Planner.SECURE,
                speed_fraction=1.0 if planner == Planner.BASELINE else None,
            )
    except NoPathError as exc:
        return str(exc)
    # The paper: poor guesses stop convergence. Slower flights along the same path are more
    # conservative (more feasible) starts; they are tried when the first one fails. The
    # baseline too: paper_blind_corner's baseline hit the iteration limit from its first
    # guess with 12 obstacle slots (the closed loop's) and solves from the next in 0.2 s.
    # Before them, the same guess with nearer views (:data:`lookback.NEAR_VIEW_FRACTION`).
    attempts: list[tuple[Guess | float, bool, float | None]] = [(guess, True, None)]
    first = o.guess_speed_fraction if planner == Planner.SECURE else 1.0
    if o.slower_guesses:
        if planner == Planner.SECURE and o.lookback == "adaptive":
            attempts.append((guess, True, lb.NEAR_VIEW_FRACTION))
        attempts += [(frac * first, True, None) for frac in RETRY_GUESS_SPEEDS]
    return attempts


def _extra_starts(
    problem: PlanningProblem,
    planner: str,
    result: PlanResult,
    cost: SolveCost,
    cache: NLPCache,
    solve_rounds: Callable[..., tuple[_Solve, SolveCost]],
    solved: list[tuple[Guess, bool, float | None]],
) -> PlanResult:
    """Minimum-time NLPs have many local optima (the paper: "poor guesses stop convergence"):
    further cold starts at the cruise speeds ``options.extra_starts``, keeping the fastest plan
    that passes; the result reports what every start cost. A start whose guess was ``solved``
    already in this call (the same guess, dual start, no near views) is skipped: it would end in
    the same plan."""
    for frac in problem.options.extra_starts:
        if budget_spent():
            break
        g = initial_guess(problem, secure=planner == Planner.SECURE, speed_fraction=frac)
        if _solved_before(solved, g, True, None):
            continue
        solved.append((g, True, None))
        s2, c = solve_rounds(problem, planner, g, None, 0.0, cache)
        cost = cost + c
        other = _judged(problem, planner, s2, cost, cache)
        if other.ok and (not result.ok or other.final_time < result.final_time):
            result = other
    return replace(result, build_time=cost.build, solve_time=cost.solve, iterations=cost.iterations)


def _too_slow(
    problem: PlanningProblem, planner: str, s: _Solve, limit: float, cost: SolveCost
) -> PlanResult:
    """The TOO_SLOW result of a call whose solution ``s`` is longer than ``limit`` seconds (its
    trajectory kept for the record, not certified)."""
    msg = f"final time {s.T:.2f} s over the limit of {limit:.2f} s"
    return replace(
        solution_result(problem, planner, s, cost), status=PlanStatus.TOO_SLOW, message=msg
    )


def plan(
    scenario_or_problem: Scenario | PlanningProblem | str,
    planner: str = "secure",
    *,
    belief: OccupancyMap | None = None,
    x0: np.ndarray | None = None,
    warm: PlanResult | None = None,
    cache: NLPCache | None = None,
    **options: object,
) -> PlanResult:
    """Plan a minimum-time trajectory in the robot's belief.

    Parameters
    ----------
    scenario_or_problem : a :class:`~secure3d.world.spec.Scenario`, a path to a scenario YAML file,
        or a ready :class:`PlanningProblem`.
    planner : ``"secure"`` or ``"baseline"``.
    belief : the robot's map (default: the server's claim, with attacks, and no sensor evidence).
    x0 : start state (default: the scenario's start).
    warm : a previous plan from the same start to warm-start from (primal and multipliers).
    cache : compiled NLPs to reuse across calls.
    **options : :class:`~secure3d.planning.problem.PlannerOptions` fields, plus ``reactive_family``
        and ``controller``.

    Returns
    -------
    PlanResult
        With ``status`` SUCCESS only if the solver converged, every constraint holds and, for the
        secure planner, the independent certificate passed.
    """
    from pathlib import Path

    if isinstance(scenario_or_problem, (str, Path)):
        from secure3d.world.scenario import load_scenario

        scenario_or_problem = load_scenario(scenario_or_problem)
    if isinstance(scenario_or_problem, PlanningProblem):
        problem = scenario_or_problem.with_options(**options) if options else scenario_or_problem
    else:
        problem = problem_from_scenario(scenario_or_problem, belief=belief, x0=x0, **options)
    return plan_problem(problem, planner, warm=warm, cache=cache)
