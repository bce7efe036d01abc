"""The Ray backend of campaigns (``secure3d campaign --backend ray``; ``pip install secure3d[ray]``).

Each slot of :class:`RayPool` is one Ray actor (:class:`_Flier`, one CPU): a long-lived worker
process that keeps one NLP cache for every run it flies, like a worker of the process backend.
Without ``address`` a local Ray is started with ``num_cpus = workers`` and shut down at the end;
with it (``auto`` or ``ray://host:10001``) the campaign joins that cluster, and secure3d must be
installed on its nodes. An actor that dies (its node lost, its process killed) makes the run a
:class:`~secure3d.simulation.campaign_pool.Crash`, which the scheduler retries on a fresh actor;
a run over ``--run-timeout`` kills its actor. Actors belong to this driver: Ray stops them when it
exits, however it exits.

Ray is imported here only, when a Ray campaign starts.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from typing import Any

from secure3d.errors import ConfigError
from secure3d.simulation.campaign_pool import Crash, fly_safely, one_thread_each
from secure3d.simulation.campaign_records import RunRecord, _Job

__all__ = ["RayPool", "actor_env"]

#: Object store of a local Ray (bytes): runs return small records, so the minimum Ray allows.
LOCAL_OBJECT_STORE = 100 * 1024**2


class _Flier:
    """A Ray actor flying one run at a time, with this process's NLP cache."""

    def __init__(self) -> None:
        # Before CasADi loads IPOPT's OpenBLAS: the actors already fill the cores.
        one_thread_each()

    def pid(self) -> int:
        """This actor's process id."""
        return os.getpid()

    def fly(self, job: _Job) -> RunRecord:
        """Fly one job (errors become error rows)."""
        return fly_safely(job)

    def numpy_kernels(self) -> dict[str, object]:
        """The numpy kernels this actor runs (:func:`secure3d.numpy_kernels`) and its
        ``NPY_DISABLE_CPU_FEATURES`` (``env``)."""
        from secure3d._numpy_kernels import NUMPY_ENV, numpy_kernels

        return {**numpy_kernels(), "env": os.environ.get(NUMPY_ENV)}


def actor_env() -> dict[str, str]:
    """The environment every actor starts with, wherever it runs: this driver's
    ``NPY_DISABLE_CPU_FEATURES`` (set by ``import secure3d``, :mod:`secure3d._numpy_kernels`, or
    by the user), so that runs on a cluster's nodes use numpy's kernels as this machine does. A
    local Ray inherits the driver's environment anyway; a cluster's raylets were started with
    their own."""
    from secure3d._numpy_kernels import NUMPY_ENV

    value = os.environ.get(NUMPY_ENV)
    return {} if value is None else {NUMPY_ENV: value}


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError(
            "--backend ray: Ray is not installed; pip install 'secure3d[ray]'"
        ) from None
    return ray


def default_workers(address: str | None) -> int:
    """Workers when none are given: this machine's CPUs, or the cluster's with ``address``."""
    if address is None:
        return os.cpu_count() or 1
    ray = _import_ray()
    _init(ray, address, None)
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def _init(ray: Any, address: str | None, workers: int | None) -> bool:
    """Start or join Ray; True when this call started it (then :meth:`RayPool.close` stops it)."""
    if ray.is_initialized():
        return False
    kwargs: dict[str, Any] = {
        "include_dashboard": False,
        "log_to_driver": False,
        "configure_logging": False,
    }
    if address is None:
        kwargs.update(num_cpus=workers, object_store_memory=LOCAL_OBJECT_STORE)
    else:
        kwargs["address"] = address
    try:
        ray.init(**kwargs)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"--address {address}: cannot connect to Ray: {first}") from None
    return True


class RayPool:
    """``size`` Ray actors, started on first use (see the module docstring)."""

    def __init__(self, size: int, address: str | None = None) -> None:
        self.size = size
        self._ray = _import_ray()
        self._started = _init(self._ray, address, size)
        env = actor_env()
        options = {"runtime_env": {"env_vars": env}} if env else {}
        self._remote = self._ray.remote(num_cpus=1, max_restarts=0, **options)(_Flier)
        self._actors: list[Any] = [None] * size
        self._refs: dict[int, Any] = {}
        self._pids: dict[int, int] = {}

    def _actor(self, slot: int) -> Any:
        if self._actors[slot] is None:
            self._actors[slot] = self._remote.remote()
            self._pids.pop(slot, None)
        return self._actors[slot]

    def start(self, slot: int, job: _Job) -> None:
        self._refs[slot] = self._actor(slot).fly.remote(job)

    def pid(self, slot: int) -> int:
        if slot not in self._pids:
            self._pids[slot] = int(self._ray.get(self._actor(slot).pid.remote()))
        return self._pids[slot]

    def wait(self, slots: Collection[int], timeout: float) -> list[tuple[int, RunRecord | Crash]]:
        ray = self._ray
        by_ref = {self._refs[s]: s for s in slots}
        ready, _ = ray.wait(list(by_ref), num_returns=1, timeout=timeout)
        if ready:
            ready, _ = ray.wait(list(by_ref), num_returns=len(by_ref), timeout=0)
        done: list[tuple[int, RunRecord | Crash]] = []
        for ref in ready:
            slot = by_ref[ref]
            del self._refs[slot]
            try:
                done.append((slot, ray.get(ref)))
            except ray.exceptions.RayActorError as exc:
                self.kill(slot)
                done.append((slot, Crash(f"Ray actor died ({_first_line(exc)})")))
            except ray.exceptions.RayError as exc:
                self.kill(slot)
                done.append((slot, Crash(f"Ray error ({_first_line(exc)})")))
        return done

    def kill(self, slot: int) -> None:
        actor, self._actors[slot] = self._actors[slot], None
        self._refs.pop(slot, None)
        self._pids.pop(slot, None)
        if actor is not None:
            self._ray.kill(actor, no_restart=True)

    def close(self) -> None:
        for slot in range(self.size):
            try:
                self.kill(slot)
            except Exception:  # noqa: BLE001 - the cluster may already be gone
                pass
        if self._started and self._ray.is_initialized():
            self._ray.shutdown()
            self._started = False


def _first_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text[:200] if text else type(exc).__name__
