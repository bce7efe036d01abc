"""Judging a secure solution: the independent certificate, the re-solves with tightened rows
that follow a rejection, and the obstacle-slot refresh that a solution the certificate passes as
it is can skip (:data:`CERTIFY_STALE`).

:func:`judged` is step 6 of :func:`secure3d.planning.solve.plan_problem`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from secure3d.planning.interrupt import BudgetSpent, budget_spent
from secure3d.planning.nlp_cache import NLPCache
from secure3d.planning.nlp_solve import SolveCost, _Solve
from secure3d.planning.outcome import failed_result, solution_result
from secure3d.planning.problem import Planner, PlanningProblem
from secure3d.planning.result import Certificate, PlanResult, PlanStatus
from secure3d.planning.slot_refresh import refresh_slots as _refresh_slots
from secure3d.planning.slot_refresh import resolve_from as _resolve_from

__all__ = [
    "CERTIFY_STALE",
    "CERTIFY_TIGHTENING",
    "START_TIGHTENING",
    "certified_as_is",
    "judged",
    "refreshed",
    "tightened_solve",
]

#: A secure solution the certificate rejects (it samples between the nodes and rolls out the real
#: manoeuvres; the NLP sees ellipsoids at the nodes) is re-solved with the clearance and visibility
#: rows of the nodes at either end of every failing interval
#: (:func:`~secure3d.planning.certificate.failing_nodes`) tightened by this much more (m), up to
#: this many times; a node keeps the tightening of earlier rounds.
#: Tightening every row instead lengthened 3D-occlusion replans (T 18.4 -> 21.0 -> 27.2 s), so the
#: node spacing grew and new violations appeared between nodes further on.
CERTIFY_TIGHTENING = (0.03, 0.08)
#: When those retries still fail at nodes the plan counts as seen from the start region (look-back
#: -1), one more re-solve tightens also those nodes' start-region rows by this much (m). The NLP's start box holds the fitted reactive
#: set at the start as well as the observed box, and the certificate counts only the observed box
#: and the body along the braking path: a replan from rest whose manoeuvres between its first
#: nodes poked 1-2 mm out of that failed every retry the same way (geb079_hidden_crate, fence
#: variant 0, seed 3307: eight plans from rest refused, and the robot held). Not in the first
#: retries: the start box is often only just large enough for the first reactive sets.
START_TIGHTENING = 0.01


def judged(
    problem: PlanningProblem,
    planner: str,
    s: _Solve,
    cost: SolveCost,
    cache: NLPCache,
    max_final_time: float = np.inf,
) -> PlanResult:
    """The result of a solve, certified (secure planner): a rejected solution is re-solved warm
    with the rows of the nodes around its failing points tightened (:data:`CERTIFY_TIGHTENING`)
    before it is reported NOT_CERTIFIED (at once if a re-solve is longer than
    ``max_final_time``)."""
    result = solution_result(problem, planner, s, cost)
    if not (result.ok and planner == Planner.SECURE and problem.options.certify):
        return result
    from secure3d.planning.certificate import failing_nodes

    def out_of_time(exc: BudgetSpent) -> PlanResult:
        failed = failed_result(
            problem, planner, PlanStatus.TIME_BUDGET, f"solver: {result.message}; {exc}"
        )
        return replace(
            failed, build_time=cost.build, solve_time=cost.solve, iterations=cost.iterations
        )

    rejected: list[Certificate] = []
    extra = np.zeros((2, problem.options.nodes))  # margin rows, start-region rows (per node)
    rounds = [(level, 0.0) for level in CERTIFY_TIGHTENING]
    rounds.append((CERTIFY_TIGHTENING[-1], START_TIGHTENING))
    try:
        cert = _certificate(s, result, problem)
        for levels in rounds:
            if cert.ok or budget_spent():
                break
            failing = failing_nodes(cert, result.times)
            if levels[1] > 0.0:  # the last round: only for failures at nodes seen from the start
                failing = failing * (np.asarray(s.assignment) < 0)
                if not failing.any():
                    break
            rejected.append(cert)
            # Tighten and re-solve from the rejected solution: never loosen anything.
            extra = np.maximum(extra, np.outer(levels, failing))
            t_, c = tightened_solve(
                problem, planner, s, cache, extra if extra[1].any() else extra[0]
            )
            cost = cost + c
            if not t_.status.ok or t_.T > max_final_time:
                break
            s = t_
            result = solution_result(problem, planner, s, cost)
            cert = _certificate(s, result, problem)
    except BudgetSpent as exc:
        return out_of_time(exc)
    result = replace(
        result, build_time=cost.build, solve_time=cost.solve, iterations=cost.iterations
    )
    status = result.status if cert.ok else PlanStatus.NOT_CERTIFIED
    msg = result.message if cert.ok else f"solver: {result.message}; certificate: {cert}"
    return replace(result, certificate=cert, status=status, message=msg, rejections=tuple(rejected))


def _certificate(s: _Solve, result: PlanResult, problem: PlanningProblem) -> Certificate:
    """The certificate of solution ``s`` (its ``result``): the one it carries if the call has
    judged it already (:func:`certified_as_is`), else a new one."""
    if s.certificate is not None:
        return s.certificate
    from secure3d.planning.certificate import certify

    return certify(result, problem)


def tightened_solve(
    problem: PlanningProblem, planner: str, s: _Solve, cache: NLPCache, extra: np.ndarray
) -> tuple[_Solve, SolveCost]:
    """Re-solve the rejected solution ``s`` with the margin rows of each node k raised by
    ``extra[k]``: warm from its multipliers, and if that fails, from its primal point with the cold
    solver's barrier schedule (on a 3D-occlusion replan the warm re-solve ran into the iteration
    limit where the cold one converged in 43 iterations); then the slot refreshes."""
    t_ = _resolve_from(problem, planner, s, cache, (s.nlp.key, s.lam_x, s.lam_g), extra)
    cost = SolveCost(t_.warm_build, t_.solve_time, t_.iterations)
    if not t_.status.ok and not budget_spent():
        t_ = _resolve_from(problem, planner, s, cache, None, extra)
        cost = cost + SolveCost(0.0, t_.solve_time, t_.iterations)
    t_, c = refreshed(problem, planner, t_, cache, extra_margin=extra)
    return t_, cost + c


#: A secure solution whose obstacle slots are stale (a box left out of them comes within half the
#: margin of a reactive set or sight line: ``lookback.slots_stale``) is certified as it is before
#: its slots are refreshed. If the certificate passes it, the refresh's re-solve is skipped and
#: the plan keeps that solution: optimal for a relaxation, so no slower than the re-solve's. If it
#: fails, the slots are refreshed as before, for the cost of one certificate. The NLP's rows are a
#: sufficient condition only (an ellipsoid round each manoeuvre, one sight line per node); the
#: certificate judges the paper's definition against every box whatever the slots, rolling out
#: the manoeuvres and searching every earlier view, so a left-out box that cuts a node's ellipsoid
#: or sight-line hull can still leave a certified plan. In flight the tracking guard watches the
#: tube as for any plan. Measured (``benchmarks/ab_campaign.py``, seed 5701, 50 variants of 5
#: families; results/session57.md): the same 50 outcomes, IPOPT iterations 16,401 -> 15,378 (22
#: variants fewer, 3 more); cold ``plan()`` over maps/: cloud_server 61 -> 42 and forest 98 -> 67
#: iterations, the rest the same.
CERTIFY_STALE = True


def refreshed(
    problem: PlanningProblem,
    planner: str,
    s: _Solve,
    cache: NLPCache,
    extra_margin: float | np.ndarray = 0.0,
    start: tuple | None = None,
) -> tuple[_Solve, SolveCost]:
    """Solution ``s`` with its obstacle slots refreshed (:func:`~.slot_refresh.refresh_slots`, with
    ``extra_margin`` and ``start``), and what that cost; or, if its slots are stale and it
    certifies as it is (:data:`CERTIFY_STALE`, :func:`certified_as_is`), ``s`` itself with that
    certificate."""
    return _refresh_slots(
        problem,
        planner,
        s,
        cache,
        extra_margin=extra_margin,
        start=start,
        accept=lambda stale: certified_as_is(problem, planner, stale),
    )


def certified_as_is(problem: PlanningProblem, planner: str, s: _Solve) -> Certificate | None:
    """The passed certificate of a secure solution ``s`` (one whose slots are stale, when
    :func:`refreshed` asks), judged as it is; None otherwise: not the secure planner, not
    certified by the call, the certificate failed, or the budget ran out while it judged (then
    the slots are refreshed, and the caller's own certificate meets the budget)."""
    o = problem.options
    if not (CERTIFY_STALE and planner == Planner.SECURE and o.certify and s.status.ok):
        return None
    from secure3d.planning.certificate import certify

    try:
        cert = certify(solution_result(problem, planner, s, SolveCost()), problem)
    except BudgetSpent:
        return None
    return cert if cert.ok else None
