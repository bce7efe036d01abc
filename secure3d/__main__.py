"""``python -m secure3d`` and the ``secure3d`` command: :func:`run` is the entry point.

It imports the command line inside a ``try``, so a Ctrl-C that arrives while the modules are
still loading ends in the same one line and exit status 130 as one that arrives later
(:func:`secure3d.cli.main` handles the rest). The Ctrl-C is also recorded, so that a library
whose import swallows the KeyboardInterrupt (a bare ``except``) cannot make the command ignore it:
under load, a Ctrl-C 0.15 s after start was lost so and the whole flight ran.

A fatal signal in native code (SIGSEGV, SIGBUS, SIGFPE, SIGABRT, SIGILL) prints every thread's
Python stack to stderr (:mod:`faulthandler`) before the process dies, so a crash inside CasADi,
numba or Open3D says where it happened instead of ending with an empty stderr.
"""

from __future__ import annotations

import sys


def run() -> int:
    """Import and run :func:`secure3d.cli.main` on ``sys.argv[1:]``; return its exit status."""
    import faulthandler
    import signal

    if not faulthandler.is_enabled():
        faulthandler.enable(all_threads=True)
    seen: list[int] = []

    def on_sigint(signum: int, frame: object) -> None:
        seen.append(signum)  # kept even if a library's import swallows the KeyboardInterrupt
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        from secure3d.cli import main
    except KeyboardInterrupt:
        seen.append(signal.SIGINT)
    finally:
        signal.signal(signal.SIGINT, previous)
    if seen:
        sys.stderr.write("secure3d: error: interrupted\n")
        return 130
    return main()


if __name__ == "__main__":
    raise SystemExit(run())
