"""Ctrl-C for the command line: a clean stop within a second, whatever is running.

Python turns SIGINT into :class:`KeyboardInterrupt` at the next bytecode, which is a clean stop
almost everywhere. Four places are not clean, all measured with ``secure3d simulate``:

- CasADi catches the exception while it builds or evaluates a function, logs
  ``KeyboardInterruptException`` and carries on (a flight interrupted at 0.6 s finished 6.8 s
  later with exit status 0);
- raised while a numba kernel or CasADi's ``__array__`` returns, it surfaces as
  ``SystemError: ... returned a result with an exception set``;
- raised while a pybind11 module initialises, as ``ImportError("initialization failed")``;
- raised inside a Python function that C calls through ctypes (llvmlite's object-cache hooks,
  which run whenever numba compiles or loads a kernel), ctypes prints "Exception ignored" and
  returns to C with the hook half done: the compile carries on, or the process dies of SIGSEGV
  (seen once in CI, a Ctrl-C 2.5 s into ``secure3d simulate``).

So :func:`cli_interrupts` installs a handler that, on the first Ctrl-C, records the request,
starts a watchdog and raises :class:`KeyboardInterrupt` as usual, unless the interrupted code is
a ctypes callback (:func:`inside_c_callback`): then it ends the process at once, as the watchdog
would. The command line reports any exception that ends a requested stop as "interrupted"
(:func:`requested`). If the command has not
returned ``grace`` seconds later (the exception was swallowed), the watchdog removes the
temporary files of unfinished writes (:func:`secure3d.outputs.remove_temporaries`), prints the
same line and ends the process with status 130. A second Ctrl-C does that at once.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator
from types import FrameType

from secure3d.outputs import remove_temporaries

__all__ = [
    "C_CALLBACK_PACKAGES",
    "EXIT_INTERRUPTED",
    "cli_interrupts",
    "held_sigint",
    "inside_c_callback",
    "requested",
]

#: Exit status after Ctrl-C (128 + SIGINT, as a shell reports it).
EXIT_INTERRUPTED = 130

_requested = threading.Event()


def requested() -> bool:
    """True once Ctrl-C was pressed inside :func:`cli_interrupts`."""
    return _requested.is_set()


#: Packages whose Python functions C calls through ctypes, where an exception cannot unwind.
C_CALLBACK_PACKAGES = ("llvmlite",)


def inside_c_callback(frame: FrameType | None) -> bool:
    """True if ``frame`` or a frame it was called from belongs to :data:`C_CALLBACK_PACKAGES`.

    The chain of a ctypes callback's frames leads back through the package's Python frame that
    made the foreign call, so checking the file names of the chain finds it.
    """
    parts = tuple(f"{os.sep}{name}{os.sep}" for name in C_CALLBACK_PACKAGES)
    while frame is not None:
        if any(part in frame.f_code.co_filename for part in parts):
            return True
        frame = frame.f_back
    return False


def _exit_now(message: str) -> None:
    remove_temporaries()
    with contextlib.suppress(OSError, ValueError):
        sys.stderr.write(message + "\n")
        sys.stderr.flush()
    os._exit(EXIT_INTERRUPTED)


@contextlib.contextmanager
def cli_interrupts(message: str, grace: float = 0.7) -> Iterator[None]:
    """Run a command so that Ctrl-C ends it within ``grace`` seconds (see the module doc).

    ``message`` is the line printed if the watchdog or a second Ctrl-C ends the process. Outside
    the main thread it changes nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    watchdog: list[threading.Timer] = []

    def on_sigint(signum: int, frame: FrameType | None) -> None:
        if _requested.is_set() or inside_c_callback(frame):
            _exit_now(message)
        _requested.set()
        timer = threading.Timer(grace, _exit_now, args=(message,))
        timer.daemon = True
        timer.start()
        watchdog.append(timer)
        raise KeyboardInterrupt

    _requested.clear()
    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield
    finally:
        for timer in watchdog:
            timer.cancel()
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
        _requested.clear()


@contextlib.contextmanager
def held_sigint(event: threading.Event, message: str = "interrupted") -> Iterator[None]:
    """Hold a Ctrl-C that arrives inside the block in ``event`` (which code inside may poll, as
    IPOPT's stop callback does) and raise it as ``KeyboardInterrupt(message)`` when the block ends.

    For code that must not see the exception mid-way: a pybind11 module initialising, a CasADi
    solve. Outside the main thread (where Python takes no signals) it changes nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    event.clear()
    previous = signal.signal(signal.SIGINT, lambda signum, frame: event.set())
    try:
        yield
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    if event.is_set():
        event.clear()
        raise KeyboardInterrupt(message)
