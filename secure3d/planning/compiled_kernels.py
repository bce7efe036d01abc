"""The node kernels' derivative Functions compiled to C, cached in the user's cache directory.

CasADi evaluates an SX Function in its virtual machine, a few nanoseconds an instruction. The
Lagrangian Hessian of a quadrotor's node has 16,000-26,000 of them, so evaluating the kernels was
a third of a closed-loop IPOPT iteration (forest, 12 obstacle slots: Hessian 12.5 ms, Jacobian
3.1 ms, of ~30-40 ms an iteration). The same instructions compiled by the system's C compiler run
2-5x faster (Hessian 6.4 ms, Jacobian 1.8 ms), with the same values bit for bit: CasADi's generated
code performs the same IEEE operations in the same order, and ``-ffp-contract=off`` keeps the
compiler from fusing a product and a sum into one rounding. Every library loaded is checked
against the virtual machine on random inputs before it is used.

A kernel is compiled once per machine. Its library is named by a digest of the kernel (its
serialised SX graph), the inputs it is differentiated in, CasADi's version, the compiler's version
and the flags, and kept under

    $SECURE3D_KERNEL_CACHE_DIR, else $SECURE3D_CACHE_DIR/kernels,
    else $XDG_CACHE_HOME/secure3d/kernels, else ~/.cache/secure3d/kernels

The libraries stay within ``$SECURE3D_KERNEL_CACHE_MB`` (default 256 MB, a few thousand kernel
shapes): when a compile lands beyond it, the least recently loaded go (:func:`prune`).

``$SECURE3D_KERNEL_COMPILE`` chooses when (a kernel without a library runs in the VM meanwhile):

- ``auto`` (the default): a kernel some earlier process met too (a mark in the cache says so) is
  compiled in the background; one met for the first time is not. Compiling beside flights costs
  them time on a 2-core machine: with every flight of ``maps/`` compiling its kernels at first
  sight, their plan calls took 1.09x the VM's in all (one real-scan flight 8.6 s instead of 2.7 s;
  alone it lost nothing). So a one-off run pays nothing, and repeated runs get the libraries;
- ``background``: compile at first sight, by a background thread at a low priority, first quickly
  (``-O0``, ~1 s for the largest kernel: ready for the next NLP built, usually the next plan
  call), then well (``-O1``, ~6 s); each NLP built afterwards picks the best library there is.
  Campaigns fly in this mode (:func:`default_mode`): many runs of the same kernels;
- ``now``: compile (``-O1``) before the first use and wait (benchmarks, ``make warm``);
- ``off``: never compile.

Without a C compiler (``$CC``, else ``cc``, ``gcc`` or ``clang`` on the PATH) every kernel runs in
the virtual machine, with the same results. A compiler that fails is not asked again in the
process. A compile that outlives the process still finishes and moves its library into place (the
move is part of the command); a lock file per library keeps processes that share the cache from
compiling the same kernel at once.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import logging
import os
import platform
import queue
import shlex
import shutil
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from secure3d.errors import ConfigError

__all__ = [
    "CACHE_MB_ENV",
    "MODE_ENV",
    "MODES",
    "KernelTag",
    "best",
    "cache_cap_bytes",
    "cache_root",
    "mode",
    "prune",
    "status",
    "wait",
]

log = logging.getLogger(__name__)

MODE_ENV = "SECURE3D_KERNEL_COMPILE"
MODES = ("auto", "background", "now", "off")
_DEFAULT_MODE = ["auto"]  # the mode when the environment names none (see default_mode)
#: Optimisation levels, quickest to compile first: the background thread compiles every kernel at
#: the first level before any at the second, and a lookup takes the last level present.
LEVELS = ("-O0", "-O1")
#: Flags of every compile: no contraction of a product and a sum into one rounding (an FMA), which
#: would change values in the last bit.
FLAGS = ("-fPIC", "-shared", "-ffp-contract=off")
#: A lock older than this (s) belongs to a compile that died: it no longer blocks.
STALE_LOCK = 900.0
#: The longest a compile may take (s).
COMPILE_TIMEOUT = 900.0
#: Random inputs a loaded library is checked on against the virtual machine.
CHECK_DRAWS = 3
#: The environment variable capping the cache's libraries (MB), and the cap without it. When a
#: compile lands and the libraries exceed it, the least recently used go (:func:`prune`).
CACHE_MB_ENV = "SECURE3D_KERNEL_CACHE_MB"
DEFAULT_CACHE_MB = 256.0
#: A mark of a kernel met (mode ``auto``) with no library is dropped after this many days unseen.
SEEN_MARK_DAYS = 30.0


def mode() -> str:
    """The compile mode: ``$SECURE3D_KERNEL_COMPILE``, else the default (see the module)."""
    value = os.environ.get(MODE_ENV, "").strip().lower() or _DEFAULT_MODE[0]
    if value not in MODES:
        raise ConfigError(
            f"environment variable {MODE_ENV}: must be one of {', '.join(MODES)}, got {value!r}"
        )
    return value


@contextlib.contextmanager
def default_mode(value: str) -> Iterator[None]:
    """Within the block, ``value`` is the mode when ``$SECURE3D_KERNEL_COMPILE`` names none."""
    if value not in MODES:
        raise ConfigError(f"compile mode: must be one of {', '.join(MODES)}, got {value!r}")
    before = _DEFAULT_MODE[0]
    _DEFAULT_MODE[0] = value
    try:
        yield
    finally:
        _DEFAULT_MODE[0] = before


def cache_root() -> Path:
    """The folder of compiled kernels (see the module)."""
    explicit = os.environ.get("SECURE3D_KERNEL_CACHE_DIR")
    if explicit:
        return Path(explicit).expanduser()
    shared = os.environ.get("SECURE3D_CACHE_DIR")
    if shared:
        return Path(shared).expanduser() / "kernels"
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "secure3d" / "kernels"


@functools.cache
def _compiler() -> tuple[str, str] | None:
    """(path, first line of ``--version``) of the C compiler, or None (also on a system without a
    POSIX shell, which the compile command needs)."""
    if os.name != "posix" or not Path("/bin/sh").exists():
        return None
    names = [os.environ["CC"]] if os.environ.get("CC") else ["cc", "gcc", "clang"]
    for name in names:
        path = shutil.which(name)
        if path is None:
            continue
        try:
            out = subprocess.run(
                [path, "--version"], capture_output=True, text=True, timeout=30, check=False
            )
        except (OSError, subprocess.SubprocessError):
            continue
        if out.returncode == 0:
            return path, (out.stdout.splitlines() or [""])[0]
    return None


@dataclass(frozen=True)
class KernelTag:
    """What names a derivative Function of a node kernel: a digest of the kernel's SX graph, the
    inputs it is differentiated in and the derivative (``jac`` or ``hess``)."""

    kernel_digest: str
    dec: tuple[int, ...]
    role: str

    @staticmethod
    def of(kernel: ca.Function, dec: tuple[int, ...], role: str) -> KernelTag:
        """The tag of ``kernel``'s derivative ``role`` in inputs ``dec``."""
        if not isinstance(kernel, ca.Function):
            raise ConfigError(f"KernelTag.of: kernel must be a casadi.Function, got {kernel!r}")
        if not all(isinstance(d, (int, np.integer)) and 0 <= d < kernel.n_in() for d in dec):
            raise ConfigError(
                f"KernelTag.of: dec must be input indices of {kernel.name()} "
                f"(0..{kernel.n_in() - 1}), got {dec!r}"
            )
        digest = hashlib.sha256(kernel.serialize().encode()).hexdigest()
        return KernelTag(digest, tuple(int(d) for d in dec), str(role))

    def with_role(self, role: str) -> KernelTag:
        """The tag of the same kernel's derivative ``role`` (no second serialisation)."""
        return KernelTag(self.kernel_digest, self.dec, str(role))

    def digest(self, compiler_version: str) -> str:
        """The library's file name stem for this compiler."""
        h = hashlib.sha256()
        for part in (
            self.kernel_digest,
            repr(self.dec),
            self.role,
            ca.__version__,
            platform.machine(),
            compiler_version,
            " ".join(FLAGS),
        ):
            h.update(part.encode())
            h.update(b"\0")
        return h.hexdigest()[:24]


class _State:
    """What this process knows: loaded libraries, failures, the background queue."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.loaded: dict[str, tuple[int, ca.Function]] = {}  # stem -> (level index, Function)
        self.bad: set[str] = set()  # stems whose library failed the check or would not load
        self.seen: dict[str, bool] = {}  # stem -> whether an earlier process met it (mode auto)
        self.failed: set[tuple[str, int]] = set()  # (stem, level) the compiler failed on
        self.queued: set[tuple[str, int]] = set()
        self.jobs: queue.PriorityQueue = queue.PriorityQueue()
        self.worker: threading.Thread | None = None
        self.order = 0
        self.pid = os.getpid()


_STATE = _State()


def _state() -> _State:
    """This process's state: a child forked from a process with a background thread starts anew
    (the thread and its queue stayed in the parent)."""
    global _STATE
    if _STATE.pid != os.getpid():
        _STATE = _State()
    return _STATE


def _paths(stem: str, level: int) -> tuple[Path, Path, Path]:
    root = cache_root()
    return (
        root / f"{stem}.c",
        root / f"{stem}{LEVELS[level]}.so",
        root / f"{stem}{LEVELS[level]}.lock",
    )


def _present_level(stem: str) -> int:
    """The highest level whose library exists, or -1."""
    for level in range(len(LEVELS) - 1, -1, -1):
        if _paths(stem, level)[1].exists():
            return level
    return -1


def _random_inputs(fn: ca.Function, rng: np.random.Generator) -> list[np.ndarray]:
    return [rng.normal(size=fn.sparsity_in(i).shape) for i in range(fn.n_in())]


def _same_outputs(a: ca.Function, b: ca.Function) -> bool:
    """Whether ``a`` and ``b`` give the same outputs, bit for bit, on :data:`CHECK_DRAWS` draws of
    random inputs."""
    rng = np.random.default_rng(20261127)
    for _ in range(CHECK_DRAWS):
        args = _random_inputs(a, rng)
        out_a, out_b = a.call(args), b.call(args)
        for x, y in zip(out_a, out_b, strict=True):
            xa, ya = np.asarray(ca.DM(x).nonzeros()), np.asarray(ca.DM(y).nonzeros())
            if xa.shape != ya.shape or not np.array_equal(xa, ya, equal_nan=True):
                return False
    return True


def _load(fn: ca.Function, stem: str, level: int) -> ca.Function | None:
    """The library of ``stem`` at ``level`` as a Function, if it loads and matches ``fn``."""
    so = _paths(stem, level)[1]
    try:
        ext = ca.external(fn.name(), str(so))
        ok = (
            ext.n_in() == fn.n_in()
            and ext.n_out() == fn.n_out()
            and all(ext.sparsity_in(i) == fn.sparsity_in(i) for i in range(fn.n_in()))
            and all(ext.sparsity_out(i) == fn.sparsity_out(i) for i in range(fn.n_out()))
            and _same_outputs(fn, ext)
        )
    except RuntimeError as exc:
        log.warning("compiled kernel %s does not load (%s); using CasADi's VM", so, exc)
        return None
    if not ok:
        log.warning("compiled kernel %s differs from CasADi's VM; not used", so)
        return None
    with contextlib.suppress(OSError):  # its time of last use, for :func:`prune`
        os.utime(so)
    return ext


def cache_cap_bytes() -> float:
    """The cap on the cache's libraries: ``$SECURE3D_KERNEL_CACHE_MB`` (MB), else the default."""
    raw = os.environ.get(CACHE_MB_ENV, "").strip()
    try:
        mb = float(raw) if raw else DEFAULT_CACHE_MB
    except ValueError:
        mb = -1.0
    if not mb > 0:
        raise ConfigError(
            f"environment variable {CACHE_MB_ENV}: must be a positive number of MB, got {raw!r}"
        )
    return mb * 1e6


def prune(cap_bytes: float | None = None, spare: str | None = None) -> list[Path]:
    """Remove the least recently used libraries (by their time of last load) until the rest fit in
    ``cap_bytes`` (default :func:`cache_cap_bytes`), never one this process has loaded nor those of
    kernel ``spare`` (a digest stem: the one just compiled), and marks
    of kernels met with no library that were not met for :data:`SEEN_MARK_DAYS`. Returns what it
    removed."""
    cap = cache_cap_bytes() if cap_bytes is None else float(cap_bytes)
    if not cap >= 0.0:
        raise ConfigError(f"prune: cap_bytes must be a number >= 0, got {cap_bytes!r}")
    root = cache_root()
    keep = set(_state().loaded) | ({spare} if spare else set())
    removed: list[Path] = []
    try:
        stats = [(p, p.stat()) for p in root.glob("*.so")]
        libs = sorted(((st.st_mtime, st.st_size, p) for p, st in stats), key=lambda t: t[0])
        total = sum(size for _, size, _ in libs)
        for _, size, path in libs:
            if total <= cap:
                break
            if path.name[:24] in keep:
                continue
            path.unlink(missing_ok=True)
            removed.append(path)
            total -= size
        stale = time.time() - SEEN_MARK_DAYS * 86400.0
        with_library = {p.name[:24] for _, _, p in libs if p not in removed}
        for mark in root.glob("*.seen"):
            if mark.stem not in with_library and mark.stat().st_mtime < stale:
                mark.unlink(missing_ok=True)
                removed.append(mark)
    except OSError as exc:  # another process pruning at once, or an unreadable cache
        log.warning("pruning the kernel cache %s: %s", root, exc)
    return removed


def _write_source(fn: ca.Function, source: Path) -> None:
    """``fn``'s C code into ``source``, atomically (a reader never sees half a file)."""
    gen = ca.CodeGenerator(fn.name(), {"with_header": False})
    gen.add(fn)
    source.parent.mkdir(parents=True, exist_ok=True)
    tmp = source.with_name(f"{source.name}.{os.getpid()}.tmp")
    tmp.write_text(gen.dump())
    os.replace(tmp, source)


def _command(cc: str, stem: str, level: int, background: bool) -> str:
    """The shell command compiling ``stem`` at ``level``: into a temporary file, moved into place,
    then the lock (and after the last level the source) removed, even when the process that
    started it has exited. In the background at a low priority (``nice``)."""
    source, so, lock = _paths(stem, level)
    tmp = so.with_name(f"{so.name}.{os.getpid()}.tmp")
    q = shlex.quote
    args = (cc, LEVELS[level], *FLAGS, str(source), "-o", str(tmp))
    nice = shutil.which("nice") if background else None
    compile_ = " ".join(q(a) for a in ((nice, "-n", "10", *args) if nice else args))
    last = level == len(LEVELS) - 1
    tail = f"rm -f {q(str(lock))}" + (f" {q(str(source))}" if last else "")
    return (
        f"{compile_} && mv -f {q(str(tmp))} {q(str(so))}; rc=$?; rm -f {q(str(tmp))}; {tail}; "
        "exit $rc"
    )


def _take_lock(lock: Path) -> bool:
    """Create ``lock`` exclusively (a stale one is replaced); False if another process holds it."""
    try:
        if lock.exists() and time.time() - lock.stat().st_mtime > STALE_LOCK:
            lock.unlink(missing_ok=True)
        fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return False
    except OSError as exc:
        log.warning("cannot lock %s (%s); not compiling", lock, exc)
        return False
    os.write(fd, str(os.getpid()).encode())
    os.close(fd)
    return True


def _compile(st: _State, cc: str, stem: str, level: int, background: bool) -> bool:
    """Compile ``stem``'s source at ``level`` unless another process is at it (its lock is held).
    Returns whether the library is there afterwards; a failure is remembered in ``st``."""
    source, so, lock = _paths(stem, level)
    if so.exists():
        return True
    if not source.exists() or not _take_lock(lock):
        return False
    with subprocess.Popen(
        ["/bin/sh", "-c", _command(cc, stem, level, background)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        start_new_session=True,  # a Ctrl-C of the planner does not kill the compile
    ) as proc:
        try:
            _, err = proc.communicate(timeout=COMPILE_TIMEOUT)
        except subprocess.TimeoutExpired:
            proc.kill()
            _, err = proc.communicate()
    if proc.returncode != 0:
        st.failed.add((stem, level))
        log.warning("compiling kernel %s (%s) failed: %s", stem, LEVELS[level], err.decode()[-500:])
        return False
    prune(spare=stem)  # the cache stays within its cap
    return so.exists()


def _work(st: _State) -> None:
    """The background thread: compile the queued (level, order, stem) jobs, lowest level first."""
    found = _compiler()
    while True:
        level, _, stem = st.jobs.get()
        try:
            if found is not None and (stem, level) not in st.failed:
                _compile(st, found[0], stem, level, background=True)
        except Exception as exc:  # never let the thread die on one kernel
            log.warning("compiling kernel %s failed: %s", stem, exc)
        finally:
            with st.lock:
                st.queued.discard((stem, level))
            st.jobs.task_done()


def _enqueue(st: _State, fn: ca.Function, stem: str) -> None:
    """Queue ``stem``'s missing levels for the background thread (writing its source first)."""
    missing = [lv for lv in range(len(LEVELS)) if not _paths(stem, lv)[1].exists()]
    with st.lock:
        missing = [lv for lv in missing if (stem, lv) not in st.queued | st.failed]
        if not missing:
            return
        source = _paths(stem, 0)[0]
        if not source.exists():
            _write_source(fn, source)
        for lv in missing:
            st.queued.add((stem, lv))
            st.order += 1
            st.jobs.put((lv, st.order, stem))
        if st.worker is None:
            st.worker = threading.Thread(
                target=_work, args=(st,), name="secure3d-kernel-cc", daemon=True
            )
            st.worker.start()


def _seen_elsewhere(stem: str) -> bool:
    """Whether an earlier process met kernel ``stem`` (its mark in the cache names another
    process); marks it as met by this one if not marked yet."""
    mark = cache_root() / f"{stem}.seen"
    try:
        if mark.exists():
            os.utime(mark)  # met again: :func:`prune` keeps marks met in the last days
            return mark.read_text().strip() != str(os.getpid())
        mark.parent.mkdir(parents=True, exist_ok=True)
        mark.write_text(str(os.getpid()))
    except OSError:
        return False
    return False


def _compile_now(st: _State, fn: ca.Function, cc: str, stem: str) -> int:
    """Compile ``stem`` at the last level and wait (also for another process compiling it); the
    level present afterwards (-1: none)."""
    top = len(LEVELS) - 1
    source, so, lock = _paths(stem, top)
    if not source.exists():
        _write_source(fn, source)
    deadline = time.monotonic() + COMPILE_TIMEOUT
    while (stem, top) not in st.failed and not _compile(st, cc, stem, top, background=False):
        if so.exists() or not lock.exists() or time.monotonic() > deadline:
            break  # done elsewhere, or that compile gave up (its lock is gone)
        time.sleep(0.1)
    return _present_level(stem)


def best(fn: ca.Function, tag: KernelTag) -> ca.Function:
    """The fastest Function with ``fn``'s values: its compiled library if there is one (loaded and
    checked once per process), else ``fn`` itself, compiling it as the mode says."""
    if not isinstance(fn, ca.Function) or not isinstance(tag, KernelTag):
        raise ConfigError(f"best: expected a casadi.Function and a KernelTag, got {fn!r}, {tag!r}")
    how = mode()
    found = _compiler() if how != "off" else None
    if found is None:
        return fn
    st = _state()
    stem = tag.digest(found[1])
    if stem in st.bad:
        return fn
    top = len(LEVELS) - 1
    level = _present_level(stem)
    try:
        if how == "now" and level < top:
            level = _compile_now(st, fn, found[0], stem)
        if level < top and how == "auto" and stem not in st.seen:
            st.seen[stem] = _seen_elsewhere(stem)
        if level < top and (how == "background" or (how == "auto" and st.seen[stem])):
            _enqueue(st, fn, stem)
    except OSError as exc:  # an unwritable cache: the VM, and no second try
        log.warning("cannot compile kernel %s (%s); using CasADi's VM", stem, exc)
        st.bad.add(stem)
    have = st.loaded.get(stem)
    if level >= 0 and (have is None or have[0] < level):
        ext = _load(fn, stem, level)
        if ext is None:
            st.bad.add(stem)
            return fn
        have = (level, ext)
        st.loaded[stem] = have
    return have[1] if have is not None else fn


def wait(timeout: float | None = None) -> bool:
    """Wait for the background compiles queued so far; False if ``timeout`` (s) ran out first."""
    st = _state()
    deadline = None if timeout is None else time.monotonic() + timeout
    while True:
        with st.lock:
            busy = bool(st.queued)
        if not busy:
            return True
        if deadline is not None and time.monotonic() > deadline:
            return False
        time.sleep(0.05)


def status() -> dict[str, int]:
    """Counts for this process: libraries loaded, compiles queued or running, failures, libraries
    rejected (they would not load or gave other values)."""
    st = _state()
    with st.lock:
        return {
            "loaded": len(st.loaded),
            "queued": len(st.queued),
            "failed": len(st.failed),
            "rejected": len(st.bad),
        }
