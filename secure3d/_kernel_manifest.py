"""The compiled kernels a closed-loop flight calls, loaded before take-off.

numba turns a kernel into machine code on its first call with each set of argument types: it
loads the code from its cache (:mod:`secure3d._numba_cache`) or, when the cache has none (new
kernel sources, a fresh install), compiles it. In a new process those first calls fell inside the
flight: 31-35 loads, 0.13-0.19 s of every shipped scenario's flight, most of it in the first plan;
and with an empty cache, compilation: ``blind_corner``'s first plan took 23 s of wall time, over a
campaign's 10 s plan budget, so the outcome of a run could depend on the state of the cache.

So :func:`record` keeps, after each flight, which kernels (module and name) the flight called for
the first time in its process, with which argument types (numba signatures), in a manifest beside
the compiled kernels, and :func:`preload` loads (or compiles) every one of them in the set-up of
the next flight, before the clock starts. Kernels a set-up calls anyway (an OctoMap file's parser)
are left out: preloading them for every scenario would cost more than it saves.
A signature the kernels no longer accept (an edited kernel) is skipped. The manifest is a pickle
in the user's cache directory, trusted as numba's own cache files there are.

This module imports no other part of secure3d than the cache location and the atomic file writer,
so the simulator (which calls both functions) may import it from any layer.
"""

from __future__ import annotations

import importlib
import os
import pickle
import sys
from pathlib import Path

from secure3d._numba_cache import cache_root
from secure3d.outputs import atomic_write_bytes

__all__ = ["MANIFEST_ENV", "loaded_signatures", "manifest_path", "preload", "record"]

#: Environment variable naming the manifest file (default: see :func:`manifest_path`).
MANIFEST_ENV = "SECURE3D_KERNEL_MANIFEST"

_PACKAGE = "secure3d"


def _ours(modname: str) -> bool:
    """Whether ``modname`` is secure3d or one of its modules."""
    return modname == _PACKAGE or modname.startswith(_PACKAGE + ".")


def manifest_path() -> Path:
    """``$SECURE3D_KERNEL_MANIFEST``, else ``<kernel cache root>/flight-kernels-<python>-<numba>
    .pickle`` (signatures name numba's types, so one manifest per numba version)."""
    explicit = os.environ.get(MANIFEST_ENV)
    if explicit:
        return Path(explicit)
    import numba

    py = "".join(str(v) for v in sys.version_info[:2])
    return cache_root() / f"flight-kernels-py{py}-numba{numba.__version__}.pickle"


def _dispatchers() -> dict[tuple[str, str], object]:
    """secure3d's numba kernels in the modules imported so far, by (module, name) where defined."""
    from numba.core.registry import CPUDispatcher

    found = {}
    for modname, module in list(sys.modules.items()):
        if module is None or not _ours(modname):
            continue
        for name, value in list(vars(module).items()):
            if isinstance(value, CPUDispatcher) and value.py_func.__module__ == modname:
                found[(modname, name)] = value
    return found


def loaded_signatures() -> dict[tuple[str, str], set]:
    """Every (module, kernel name) -> the argument-type signatures compiled or loaded so far."""
    return {key: set(d.signatures) for key, d in _dispatchers().items() if d.signatures}


def _read(path: Path) -> dict[tuple[str, str], set]:
    """The manifest at ``path``; empty if there is none or it cannot be read."""
    try:
        data = pickle.loads(path.read_bytes())
    except Exception:  # noqa: BLE001 - missing or corrupt: a cache file is no error of the caller's
        return {}
    if not isinstance(data, dict):
        return {}
    return {k: set(v) for k, v in data.items() if isinstance(k, tuple) and isinstance(v, set)}


def record(path: Path | None = None, since: dict[tuple[str, str], set] | None = None) -> int:
    """Add the signatures loaded in this process (after ``since``, a :func:`loaded_signatures`
    snapshot: the flight's, not its set-up's) to the manifest, written whole, atomically, and
    only when something is new. Returns how many signatures were new; 0 if the file cannot be
    written (the next set-up then loads less, nothing else changes)."""
    since = {} if since is None else since
    called = {k: sigs - since.get(k, set()) for k, sigs in loaded_signatures().items()}
    called = {k: sigs for k, sigs in called.items() if sigs}
    if not called:  # a flight that loaded nothing new (every flight after a preload): no I/O
        return 0
    path = manifest_path() if path is None else Path(path)
    known = _read(path)
    new = 0
    for key, sigs in called.items():
        fresh = sigs - known.get(key, set())
        if fresh:
            known.setdefault(key, set()).update(fresh)
            new += len(fresh)
    if not new:
        return 0
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, pickle.dumps(known))
    except Exception:  # noqa: BLE001 - a cache that cannot be written must not fail a flight
        return 0
    return new


def preload(path: Path | None = None) -> int:
    """Load (or compile) every kernel signature of the manifest that this process has not loaded
    yet. Returns how many were loaded. Entries that no longer fit (a kernel renamed, or given
    other argument types) are dropped from the manifest, so that no later set-up pays numba's
    attempt to type them again (about 50 ms each)."""
    from numba.core.registry import CPUDispatcher

    path = manifest_path() if path is None else Path(path)
    loaded = 0
    stale: dict[tuple[str, str], set] = {}
    for (modname, name), sigs in _read(path).items():
        if not _ours(modname):
            continue
        try:
            kernel = getattr(importlib.import_module(modname), name, None)
        except Exception:  # noqa: BLE001 - a module renamed or gone since the manifest was written
            kernel = None
        if not isinstance(kernel, CPUDispatcher):
            stale[(modname, name)] = set(sigs)
            continue
        for sig in sigs:
            if sig in kernel.overloads:
                continue
            try:
                kernel.compile(sig)
            except Exception:  # noqa: BLE001 - a stale entry: the kernel compiles on first call
                stale.setdefault((modname, name), set()).add(sig)
                continue
            loaded += 1
    if stale:
        _drop(path, stale)
    return loaded


def _drop(path: Path, stale: dict[tuple[str, str], set]) -> None:
    """Rewrite the manifest at ``path`` without the ``stale`` signatures (read afresh, written
    whole and atomically; a file that cannot be written is left as it is)."""
    known = _read(path)
    for key, sigs in stale.items():
        if key in known:
            known[key] -= sigs
            if not known[key]:
                del known[key]
    try:
        atomic_write_bytes(path, pickle.dumps(known))
    except Exception:  # noqa: BLE001 - a cache that cannot be written must not fail a set-up
        return
