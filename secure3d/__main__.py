"""``python -m secure3d`` is the ``secure3d`` command line."""

from secure3d.cli import main

raise SystemExit(main())
