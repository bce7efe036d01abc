"""``secure3d campaign`` and ``secure3d campaign-merge`` (logic in
:mod:`secure3d.simulation.campaign` and :mod:`secure3d.simulation.campaign_store`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from secure3d.cli_common import (
    _SCENARIO_HELP,
    _add_planner_options,
    _add_replan_defer,
    _planner_options,
)


def _planner_names(text: str) -> tuple[str, ...]:
    names = tuple(p.strip() for p in text.split(",") if p.strip())
    from secure3d.planning.problem import Planner  # here: `secure3d show` never loads CasADi

    bad = [p for p in names if p not in tuple(Planner)]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"expected a comma-separated list of secure, baseline (got {text!r})"
        )
    return names


def _campaign_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", type=Path, help="base " + _SCENARIO_HELP)
    parser.add_argument("-n", type=int, required=True, help="number of hidden-obstacle variants")
    parser.add_argument(
        "--planners",
        type=_planner_names,
        default=("secure", "baseline"),
        metavar="LIST",
        help="comma-separated planners to fly (secure,baseline)",
    )
    parser.add_argument("--seed", type=int, default=0, metavar="S", help="seed of the variants (0)")
    parser.add_argument(
        "--workers", type=int, metavar="W", help="worker processes (default: the number of CPUs)"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("out/campaign"),
        metavar="DIR",
        help="output folder (out/campaign)",
    )
    from secure3d.world.family_registry import FAMILIES

    parser.add_argument(
        "--kind",
        choices=("auto", "corner", "forest", *FAMILIES),
        default="auto",
        # argparse formats help with %: a family's "30-90 % of" must not read as a format
        help="where hidden obstacles go (auto), or a scenario family: "
        + "; ".join(f"{f.name}: {f.description}" for f in FAMILIES.values()).replace("%", "%%"),
    )
    parser.add_argument(
        "--count", type=int, default=1, metavar="C", help="hidden obstacles per variant (1)"
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_replan_defer(parser)
    _add_planner_options(parser)
    group = parser.add_argument_group("scale and faults")
    group.add_argument(
        "--backend",
        choices=("process", "ray"),
        default="process",
        help="process: worker processes here; ray: Ray actors (pip install 'secure3d[ray]')",
    )
    group.add_argument(
        "--address",
        metavar="ADDR",
        help="with --backend ray: join this Ray cluster (auto, ray://host:10001) instead of a"
        " local Ray",
    )
    group.add_argument(
        "--resume",
        action="store_true",
        help="continue the campaign in --out: fly only the runs missing from its runs.csv",
    )
    group.add_argument(
        "--shard",
        metavar="K/N",
        help="fly only variants i with i %% N == K-1 (combine shards with campaign-merge)",
    )
    group.add_argument(
        "--run-timeout",
        type=float,
        metavar="S",
        help="stop a run after S wall seconds (set-up included): an error row",
    )
    group.add_argument(
        "--retries",
        type=int,
        default=1,
        metavar="R",
        help="fly a run again up to R times when its worker dies (1)",
    )


def _campaign(args: argparse.Namespace) -> int:
    from secure3d.simulation.campaign import run_campaign

    result = run_campaign(
        args.scenario,
        args.n,
        planners=args.planners,
        seed=args.seed,
        workers=args.workers,
        out_dir=args.out,  # made once every argument is checked (nothing is left on an error)
        progress=not args.no_progress,
        kind=args.kind,
        count=args.count,
        replan_defer=args.replan_defer,
        backend=args.backend,
        address=args.address,
        resume=args.resume,
        shard=args.shard,
        run_timeout=args.run_timeout,
        retries=args.retries,
        **_planner_options(args),
    )
    print(result.summary_markdown().rstrip())
    print(f"\nwrote {result.csv_path} and {result.summary_path} (every run: runs.csv)")
    return 0


def _merge_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folders", type=Path, nargs="+", metavar="OUT", help="campaign folders")
    parser.add_argument(
        "--out", type=Path, required=True, metavar="DIR", help="folder for the merged campaign"
    )


def _merge(args: argparse.Namespace) -> int:
    from secure3d.simulation.campaign_store import merge_campaigns

    result = merge_campaigns(args.folders, args.out)
    print(result.summary_markdown().rstrip())
    print(f"\nwrote {result.csv_path} and {result.summary_path} (every run: runs.csv)")
    return 0
