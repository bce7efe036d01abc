"""``python -m secure3d`` and the ``secure3d`` command: :func:`run` is the entry point.

It imports the command line inside a ``try``, so a Ctrl-C that arrives while the modules are
still loading ends in the same one line and exit status 130 as one that arrives later
(:func:`secure3d.cli.main` handles the rest).
"""

from __future__ import annotations

import sys


def run() -> int:
    """Import and run :func:`secure3d.cli.main` on ``sys.argv[1:]``; return its exit status."""
    try:
        from secure3d.cli import main
    except KeyboardInterrupt:
        sys.stderr.write("secure3d: error: interrupted\n")
        return 130
    return main()


if __name__ == "__main__":
    raise SystemExit(run())
