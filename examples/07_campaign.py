"""07 - A small randomised campaign: how often does each planner collide?

The safety theorem (Proof of Safety) says the secure planner never collides, whatever the server
hid; a campaign tests it empirically. Each variant of the blind corner gets one more crate-sized
obstacle, hidden from the server and placed just behind the corner across the shortest path
(:func:`secure3d.world.attacks.hidden_obstacle_family`); every planner flies every variant with
the same camera-noise seed. Writes ``runs.csv`` and ``campaign.csv`` (one row per run) and ``summary.md``
(collision rate with a 95 % interval, goal rate, times, solve-time percentiles) and prints the
summary. ``secure3d campaign`` does the same for any scenario and any size.

Run headless::

    .venv/bin/python examples/07_campaign.py [--quick] [-n 6] [--workers 2] [--out out/examples]
"""

from __future__ import annotations

import sys
from pathlib import Path

from secure3d.simulation.campaign import run_campaign

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import MAPS, example_parser, planner_options


def main(argv: list[str] | None = None) -> int:
    parser = example_parser(
        __doc__,
        quick_help="smoke test: 2 variants, baseline only, 20 collocation nodes, in this process",
    )
    parser.add_argument("-n", type=int, default=6, help="number of variants")
    parser.add_argument("--workers", type=int, help="worker processes (default: CPU count)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the variants")
    args = parser.parse_args(argv)

    n, workers, planners, options = args.n, args.workers, ("secure", "baseline"), {}
    if args.quick:
        n, workers, planners, options = 2, 1, ("baseline",), planner_options(quick=True)
    folder = args.out / "07_campaign"
    # The example starts over each time; a campaign otherwise refuses a folder holding another's
    # runs.csv (continue one with resume=True).
    (folder / "runs.csv").unlink(missing_ok=True)
    result = run_campaign(
        MAPS / "blind_corner.yaml",
        n,
        planners,
        seed=args.seed,
        workers=workers,
        out_dir=folder,
        progress=not args.quick,
        **options,
    )
    print(result.summary_markdown())
    print(f"wrote {result.csv_path} and {result.summary_path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
