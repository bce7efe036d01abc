"""Stopping IPOPT mid-solve: on Ctrl-C, and when a plan call's wall-time budget is spent.

CasADi polls Python's signals during a solve, but on Ctrl-C it only logs
``WARNING("KeyboardInterruptException")`` and lets IPOPT run on to the end (measured: a 6.6 s
forest solve interrupted after 1.5 s finished with ``Solve_Succeeded``), after which the planner's
retry loop would even start the next attempt. So while a solve runs, :func:`interruptible`
replaces the SIGINT handler by one that only records the request, and every IPOPT solver carries
an iteration callback (:func:`stop_callback`) that answers "stop" once a request is recorded; IPOPT
then returns ``User_Requested_Stop`` and :func:`interruptible` raises :class:`KeyboardInterrupt`.

The same callback enforces a plan call's budget: inside :func:`deadline`, it also answers "stop"
once the wall clock passes the deadline, and :func:`budget_spent` tells the planner's retry loops
to stop starting solves. (IPOPT's own ``max_wall_time`` is fixed when a solver is compiled, and
compiled solvers are cached across calls, so it cannot carry a per-call budget.)

Inside :func:`final_time_watch` the callback also stops a solve whose iterate's final time passes
a cap (:func:`ran_away` tells it apart): a slot refresh's re-solve that runs away from the solution
it started on (``planning/slot_refresh.py``).

A solve that runs longer than :data:`SOLVE_HEARTBEAT_SECONDS` logs an INFO line (iterations and
final time so far) from the same callback, and again every as many seconds, so that ``secure3d
plan`` on a hard map says what it is doing instead of staying silent (the command line shows the
library's INFO lines on stderr).
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Iterator

import casadi as ca

from secure3d.errors import PlanningError
from secure3d.sigint import held_sigint

__all__ = [
    "BudgetSpent",
    "budget_spent",
    "deadline",
    "deadline_passed",
    "final_time_watch",
    "interruptible",
    "ran_away",
    "stop_callback",
    "stopped_for_budget",
]

log = logging.getLogger(__name__)

_requested = threading.Event()
_budget = threading.local()

#: Wall time (s) of one solve after which, and every as many seconds, it logs its progress.
SOLVE_HEARTBEAT_SECONDS = 5.0

#: The next IPOPT iteration is taken to cost up to this many times the longest one so far within
#: the plan call's budget (see ``_StopCallback.eval``).
ITERATION_SAFETY = 2.0


def _deadline_now() -> float:
    return getattr(_budget, "deadline", math.inf)


@contextlib.contextmanager
def final_time_watch(cap: float) -> Iterator[None]:
    """Stop the solves inside once an iterate's final time passes ``cap`` (s); :func:`ran_away`
    then tells such a stop from the budget's or Ctrl-C's."""
    if isinstance(cap, bool) or not isinstance(cap, (int, float)) or not cap > 0:
        raise PlanningError(f"final_time_watch: cap must be a time > 0 (s) or inf, got {cap!r}")
    outer = getattr(_budget, "t_cap", math.inf)
    _budget.t_cap = float(cap)
    try:
        yield
    finally:
        _budget.t_cap = outer


def final_time_cap() -> float:
    """The cap (s) of the innermost :func:`final_time_watch` of this thread (inf outside one)."""
    return float(getattr(_budget, "t_cap", math.inf))


def ran_away() -> bool:
    """Whether the last solve of this thread was stopped by its :func:`final_time_watch`."""
    return bool(getattr(_budget, "ran_away", False))


class BudgetSpent(Exception):  # noqa: N818 - a signal between the planner's layers, not an error
    """Raised by work that checks :func:`deadline_passed` as it goes (the certificate) once the
    plan call's budget is spent; the planner reports ``TIME_BUDGET``."""


def budget_spent(ahead: float = 0.0) -> bool:
    """True once the innermost :func:`deadline` of this thread, less its ``reserve`` (the time kept
    for what follows the solves), has passed, or will have passed ``ahead`` seconds from now."""
    return time.monotonic() + ahead + getattr(_budget, "reserve", 0.0) >= _deadline_now()


def deadline_passed() -> bool:
    """True once the innermost :func:`deadline` of this thread itself has passed (its reserve is
    there to be used)."""
    return time.monotonic() >= _deadline_now()


def stopped_for_budget() -> bool:
    """Whether the last solve of this thread was stopped by its budget (not by Ctrl-C)."""
    return bool(getattr(_budget, "stopped", False))


@contextlib.contextmanager
def deadline(seconds: float, reserve: float = 0.0) -> Iterator[None]:
    """Give the solves inside a wall-time budget of ``seconds`` (nested budgets keep the earlier),
    of which they leave the last ``reserve`` seconds to the work after them (:func:`budget_spent`
    counts it as spent; :func:`deadline_passed` does not)."""
    outer = _deadline_now()
    outer_longest = getattr(_budget, "longest", 0.0)
    outer_reserve = getattr(_budget, "reserve", 0.0)
    _budget.deadline = min(outer, time.monotonic() + float(seconds))
    _budget.longest = 0.0  # the longest IPOPT iteration within this budget
    _budget.reserve = float(reserve)
    try:
        yield
    finally:
        _budget.deadline = outer
        _budget.longest = outer_longest
        _budget.reserve = outer_reserve


class _StopCallback(ca.Callback):
    """IPOPT iteration callback: returns 1 (stop) once Ctrl-C was recorded or the budget is spent."""

    def __init__(self, name: str, sizes: dict[str, ca.Sparsity], t_index: int | None):
        ca.Callback.__init__(self)
        self._sizes = sizes
        self._t_index = t_index
        self.construct(name, {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "stop"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return self._sizes[ca.nlpsol_out(i)]

    def eval(self, args: list) -> list:
        # Stop when the budget would be spent before the next iteration ends: a budget is a
        # bound, not a point to overrun by one iteration. The next iteration is taken to cost up
        # to ITERATION_SAFETY times the longest one of this plan call so far (the solve's set-up
        # included): with the last iteration's length alone, calls overran a 10 s budget by up to
        # 2.1-5.7 s in campaigns under load (issue 16), where one iteration can take several
        # times the one before it (a restoration phase, a busy machine).
        now = time.monotonic()
        last = getattr(_budget, "last_iteration", None)  # set by interruptible() per solve
        _budget.last_iteration = now
        self._beat(now, args)
        gap = now - last if last is not None else 0.0
        _budget.longest = max(getattr(_budget, "longest", 0.0), gap)
        if budget_spent(ahead=ITERATION_SAFETY * _budget.longest):
            _budget.stopped = True
            return [1.0]
        if _requested.is_set():
            return [1.0]
        if self._t_index is not None and float(args[0][self._t_index]) > final_time_cap():
            _budget.ran_away = True
            return [1.0]
        return [0.0]

    def _beat(self, now: float, args: list) -> None:
        """Count the solve's iterations; log its progress once SOLVE_HEARTBEAT_SECONDS have passed
        since the solve began or since the last such line."""
        _budget.iterations = getattr(_budget, "iterations", 0) + 1
        start = getattr(_budget, "solve_start", now)
        if now < getattr(_budget, "next_beat", start + SOLVE_HEARTBEAT_SECONDS):
            return
        _budget.next_beat = now + SOLVE_HEARTBEAT_SECONDS  # one line per heartbeat, no bursts
        final = (
            "" if self._t_index is None else f", final time {float(args[0][self._t_index]):.2f} s"
        )
        log.info(
            "still solving: %d IPOPT iterations in %.0f s%s", _budget.iterations, now - start, final
        )


def stop_callback(n_x: int, n_g: int, n_p: int, t_index: int | None = None) -> ca.Callback:
    """The iteration callback for an NLP with ``n_x`` variables, ``n_g`` rows, ``n_p`` parameters,
    whose final time is variable ``t_index`` (None: no :func:`final_time_watch`).

    Keep a reference to it as long as the solver lives (CasADi does not own Python callbacks).
    """
    if t_index is not None and not (isinstance(t_index, int) and 0 <= t_index < n_x):
        raise PlanningError(
            f"stop_callback: t_index must index one of {n_x} variables, got {t_index!r}"
        )
    dense = ca.Sparsity.dense
    sizes = {
        "x": dense(n_x, 1),
        "f": dense(1, 1),
        "g": dense(n_g, 1),
        "lam_x": dense(n_x, 1),
        "lam_g": dense(n_g, 1),
        "lam_p": dense(n_p, 1),
    }
    return _StopCallback(f"secure3d_stop_{n_x}_{n_g}_{n_p}", sizes, t_index)


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """Run a solve so that Ctrl-C stops it within one IPOPT iteration and raises KeyboardInterrupt.

    Outside the main thread (where Python cannot set signal handlers) it changes nothing. It also
    starts the solve's iteration clock, by which the budget stops a solve one iteration early.
    """
    _budget.last_iteration = time.monotonic()  # the first gap includes the solve's set-up
    _budget.solve_start, _budget.iterations = _budget.last_iteration, 0
    _budget.next_beat = _budget.solve_start + SOLVE_HEARTBEAT_SECONDS
    _budget.stopped = False
    _budget.ran_away = False
    with held_sigint(_requested, "plan interrupted"):
        yield
