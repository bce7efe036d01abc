"""Workers for campaigns: where runs are flown, and how a worker that dies or hangs is handled.

A *pool* has ``size`` slots, each running at most one job at a time:

- :class:`InlinePool`: this process, one slot (``workers=1`` without ``run_timeout``);
- :class:`ProcessPool`: one spawned process per slot, each keeping one NLP cache for all its runs.
  A slot whose process dies or is killed (``run_timeout``) gets a fresh process on its next job.
  Workers die with their parent (``PR_SET_PDEATHSIG`` on Linux, and a watchdog thread that exits
  when the parent pid changes), ignore SIGINT (Ctrl-C is the parent's to handle) and run the BLAS
  under IPOPT on their own thread;
- :class:`~secure3d.simulation.campaign_ray.RayPool`: one Ray actor per slot.

:func:`schedule` drives any pool: it feeds idle slots, streams records back as runs finish, turns a
worker crash into a retry (``retries`` times) and then into an error row, and kills a run that
exceeds ``run_timeout`` (an error row; not retried).
"""

from __future__ import annotations

import functools
import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Collection, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from secure3d.errors import Secure3DError
from secure3d.simulation.campaign_records import RunRecord, _Job, error_record

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.collocation import NLPCache

__all__ = ["Crash", "InlinePool", "Pool", "ProcessPool", "fly_job", "fly_safely", "schedule"]

log = logging.getLogger("secure3d")

#: Seconds between two checks that a worker's parent is alive.
WATCHDOG_PERIOD = 1.0


@dataclass(frozen=True)
class Crash:
    """A slot's worker died before returning its run (``reason`` says how)."""

    reason: str


class Pool(Protocol):
    """What :func:`schedule` needs of a pool of workers."""

    size: int

    def start(self, slot: int, job: _Job) -> None:
        """Start ``job`` on the idle ``slot`` (starting its worker if it has none)."""

    def wait(self, slots: Collection[int], timeout: float) -> list[tuple[int, RunRecord | Crash]]:
        """Wait up to ``timeout`` s for busy ``slots``; return those finished, with their result."""

    def kill(self, slot: int) -> None:
        """Stop ``slot``'s worker now (its run is lost); the slot gets a fresh worker later."""

    def pid(self, slot: int) -> int:
        """Process id of ``slot``'s worker (started if needed)."""

    def close(self) -> None:
        """Stop every worker (idempotent)."""


@functools.cache
def _process_cache() -> NLPCache:
    """One NLP cache per process, shared by the runs that process flies."""
    from secure3d.planning.collocation import NLPCache

    return NLPCache()


def fly_job(job: _Job) -> RunRecord:
    """Fly one job (in a worker process or in-process). secure3d errors become an error row."""
    from secure3d.planning import compiled_kernels
    from secure3d.simulation.closed_loop import simulate

    t0 = time.perf_counter()
    try:
        # many runs of the same kernels: compile them at first sight (unless the user said)
        with compiled_kernels.default_mode("background"):
            result = simulate(
                job.scenario, job.planner, seed=job.seed, cache=_process_cache(), **job.options
            )
    except Secure3DError as exc:
        return error_record(job, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0)
    return RunRecord.from_result(job.variant, result)


def fly_safely(job: _Job, fly: Callable[[_Job], RunRecord] = fly_job) -> RunRecord:
    """Fly ``job`` with ``fly``; any exception becomes an error row, not a dead campaign."""
    t0 = time.perf_counter()
    try:
        return fly(job)
    except Exception as exc:  # a bug in one run must not stop the others
        return error_record(job, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0)


# ---- in this process ---------------------------------------------------------------------------


class InlinePool:
    """One slot, flown in this process (no isolation, no timeout)."""

    size = 1

    def __init__(self, fly: Callable[[_Job], RunRecord] = fly_job) -> None:
        self._job: _Job | None = None
        self._fly = fly

    def start(self, slot: int, job: _Job) -> None:
        self._job = job

    def wait(self, slots: Collection[int], timeout: float) -> list[tuple[int, RunRecord | Crash]]:
        job, self._job = self._job, None
        return [] if job is None else [(0, fly_safely(job, self._fly))]

    def kill(self, slot: int) -> None:
        self._job = None

    def pid(self, slot: int) -> int:
        return os.getpid()

    def close(self) -> None:
        self._job = None


# ---- worker processes --------------------------------------------------------------------------


def _die_with_parent(parent: int) -> None:
    """Exit when ``parent`` does: the kernel's parent-death signal (Linux) and a watchdog."""
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):  # pragma: no cover - no prctl: the watchdog remains
            pass
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        while True:
            time.sleep(WATCHDOG_PERIOD)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="secure3d-parent-watchdog", daemon=True).start()


def one_thread_each(scan_too: bool = True) -> None:
    """Threads of a worker among others that fill the cores: one for IPOPT's OpenBLAS (set before
    CasADi loads it) and, with ``scan_too``, one for a scan's trace
    (:func:`secure3d.mapping.scan.scan_threads`)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if scan_too:
        os.environ.setdefault("SECURE3D_SCAN_THREADS", "1")


def _worker_main(
    conn: multiprocessing.connection.Connection,
    parent: int,
    fly: Callable[[_Job], RunRecord] = fly_job,
    among_others: bool = True,
) -> None:
    """A worker process: fly the jobs received on ``conn`` until it closes (a scan traced in one
    thread when it is ``among_others``)."""
    _die_with_parent(parent)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    one_thread_each(scan_too=among_others)
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        conn.send(fly_safely(job, fly))


@dataclass
class _Worker:
    process: multiprocessing.process.BaseProcess
    conn: multiprocessing.connection.Connection


class ProcessPool:
    """``size`` spawned worker processes (clean interpreters: forking a parent that runs OpenMP or
    TBB threads can deadlock the child). Workers start on first use."""

    def __init__(self, size: int, fly: Callable[[_Job], RunRecord] = fly_job) -> None:
        self.size = size
        self._fly = fly
        self._context = multiprocessing.get_context("spawn")
        self._workers: list[_Worker | None] = [None] * size

    def _worker(self, slot: int) -> _Worker:
        worker = self._workers[slot]
        if worker is None or not worker.process.is_alive():
            if worker is not None:
                self.kill(slot)
            parent, child = self._context.Pipe()
            process = self._context.Process(
                target=_worker_main,
                args=(child, os.getpid(), self._fly, self.size > 1),
                daemon=True,
            )
            process.start()
            child.close()
            worker = self._workers[slot] = _Worker(process, parent)
        return worker

    def start(self, slot: int, job: _Job) -> None:
        try:
            self._worker(slot).conn.send(job)
        except OSError:  # the idle worker died since its last run: a fresh one takes the job
            self.kill(slot)
            self._worker(slot).conn.send(job)

    def pid(self, slot: int) -> int:
        return int(self._worker(slot).process.pid or 0)

    def wait(self, slots: Collection[int], timeout: float) -> list[tuple[int, RunRecord | Crash]]:
        watched: dict[object, int] = {}
        for slot in slots:
            worker = self._workers[slot]
            assert worker is not None
            watched[worker.conn] = slot
            watched[worker.process.sentinel] = slot
        ready = multiprocessing.connection.wait(list(watched), timeout)
        done: dict[int, RunRecord | Crash] = {}
        for obj in ready:
            slot = watched[obj]
            if slot not in done:
                done[slot] = self._collect(slot)
        return list(done.items())

    def _collect(self, slot: int) -> RunRecord | Crash:
        worker = self._workers[slot]
        assert worker is not None
        try:
            if worker.conn.poll():
                return worker.conn.recv()
        except (EOFError, OSError):
            pass
        worker.process.join(5)
        code = worker.process.exitcode
        self.kill(slot)
        how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit code {code}"
        return Crash(f"worker process died ({how})")

    def kill(self, slot: int) -> None:
        worker, self._workers[slot] = self._workers[slot], None
        if worker is None:
            return
        if worker.process.is_alive():
            worker.process.kill()
        worker.process.join(5)
        worker.conn.close()

    def close(self) -> None:
        for slot in range(self.size):
            self.kill(slot)


# ---- the scheduler -----------------------------------------------------------------------------


@dataclass
class _Running:
    job: _Job
    started: float
    attempt: int


def schedule(
    pool: Pool,
    jobs: Iterable[_Job | RunRecord],
    run_timeout: float | None = None,
    retries: int = 1,
    on_start: Callable[[_Job, int], object] | None = None,
) -> Iterator[tuple[_Job | None, RunRecord]]:
    """Fly ``jobs`` on ``pool``; yield ``(job, record)`` as each run finishes.

    A :class:`RunRecord` among ``jobs`` (a variant that could not be made) is yielded as it is,
    with job None. A worker crash re-queues its job at the front, up to ``retries`` times, then
    gives an error row; a run longer than ``run_timeout`` s (wall time from its start, set-up
    included) is killed and gives an error row. ``on_start(job, worker pid)`` is called as each
    run starts (tests kill workers with it). The caller closes the pool.
    """
    source = iter(jobs)
    retry: deque[tuple[_Job, int]] = deque()
    running: dict[int, _Running] = {}
    exhausted = False
    while True:
        while len(running) < pool.size and (retry or not exhausted):
            if retry:
                job, attempt = retry.popleft()
            else:
                item = next(source, None)
                if item is None:
                    exhausted = True
                    break
                if isinstance(item, RunRecord):
                    yield None, item
                    continue
                job, attempt = item, 0
            slot = min(set(range(pool.size)) - set(running))
            # The pid first: a Ray actor answers only after the run it is flying.
            pid = pool.pid(slot) if on_start is not None else 0
            pool.start(slot, job)
            running[slot] = _Running(job, time.monotonic(), attempt)
            if on_start is not None:
                on_start(job, pid)
        if not running:
            return
        yield from _collect(pool, running, retry, run_timeout, retries)


def _collect(
    pool: Pool,
    running: dict[int, _Running],
    retry: deque[tuple[_Job, int]],
    run_timeout: float | None,
    retries: int,
) -> Iterator[tuple[_Job, RunRecord]]:
    """One wait on the busy slots: yield what finished, re-queue crashes, kill overdue runs."""
    now = time.monotonic()
    timeout = 1.0
    if run_timeout is not None:
        first = min(r.started for r in running.values())
        timeout = max(0.0, min(timeout, first + run_timeout - now))
    for slot, outcome in pool.wait(list(running), timeout):
        run = running.pop(slot)
        if isinstance(outcome, RunRecord):
            yield run.job, outcome
        elif run.attempt < retries:
            log.info(
                "variant %d / %s: %s; retrying", run.job.variant, run.job.planner, outcome.reason
            )
            retry.appendleft((run.job, run.attempt + 1))
        else:
            attempts = run.attempt + 1
            reason = f"{outcome.reason} ({attempts} attempt{'s' if attempts > 1 else ''})"
            yield run.job, error_record(run.job, reason, time.monotonic() - run.started)
    if run_timeout is None:
        return
    now = time.monotonic()
    for slot, run in list(running.items()):
        if now - run.started > run_timeout:
            pool.kill(slot)
            del running[slot]
            reason = f"run timeout: stopped after {run_timeout:g} s (--run-timeout)"
            yield run.job, error_record(run.job, reason, now - run.started)
