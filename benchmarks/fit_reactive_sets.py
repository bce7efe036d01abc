"""Fit the shipped reactive-set families and store them in ``secure3d/reactive/data``.

Each family is fitted to simulated manoeuvres from ``--n-samples`` random states (validation sample
drawn after it from the same seed), written as ``<model>_<controller>.json`` (with a
``_latency<t>`` suffix for a non-zero latency), then checked on ``--check`` fresh manoeuvres drawn
from an independent seed, next to the closed form. Regenerate everything with::

    .venv/bin/python benchmarks/fit_reactive_sets.py

or one family with ``--family point_mass/braking``. ``--scenario maps/office_bt.yaml`` fits the
family of that scenario's vehicle (its limits and body radius) through the same checked path the
planner uses on demand (:func:`secure3d.reactive.family_store.fit_checked`) and ships it as
``<model>_<controller>_<scenario>.json``. Runs headless; prints one report per family.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from secure3d.dynamics import make_model
from secure3d.reactive.family_store import DATA_DIR, default_controller, save_family
from secure3d.reactive.fitting import fit_family
from secure3d.reactive.reactive_set import check_containment, closed_form_family

#: The shipped model x controller families (default limits, body radius 0.2 m).
FAMILIES = ("point_mass/braking", "point_mass/mpc", "quadrotor/braking", "diff_drive/braking")


def family_path(out_dir: Path, model: str, controller: str, latency: float) -> Path:
    """Where a family is stored: ``<model>_<controller>[_latency<t>].json``."""
    suffix = "" if latency == 0 else f"_latency{latency:g}"
    return out_dir / f"{model}_{controller}{suffix}.json"


def fit_one(name: str, args: argparse.Namespace, index: int) -> None:
    model_name, controller_name = name.split("/")
    model = make_model(model_name, body_radius=args.body_radius)
    controller = default_controller(model, controller_name, args.latency)
    seed = args.seed + 1000 * index
    t0 = time.perf_counter()
    family = fit_family(
        model,
        controller,
        args.n_samples,
        np.random.default_rng(seed),
        margin=args.margin,
        dt=args.dt,
        seed=seed,
    )
    path = save_family(
        family, family_path(Path(args.out_dir), model_name, controller_name, args.latency)
    )
    print(f"{name}: fitted in {time.perf_counter() - t0:.1f} s -> {path}")
    print(
        f"  fit sample: mean volume {family.meta['mean_volume']:.4g} m^3, "
        f"{family.meta['volume_ratio']:.4f} x closed form; validation shortfall "
        f"{family.meta['validation_shortfall']:+.4f} m"
    )
    if args.check > 0:
        rng = np.random.default_rng(args.check_seed + index)
        t0 = time.perf_counter()
        report = check_containment(family, controller, args.check, rng, dt=args.dt)
        print(f"  check ({time.perf_counter() - t0:.1f} s): {report}")
        if controller_name == "braking":
            closed = closed_form_family(model, args.latency)
            rng = np.random.default_rng(args.check_seed + index)
            report = check_containment(closed, controller, args.check, rng, dt=args.dt)
            print(f"  closed form: {report}")


def fit_scenario(path: str, args: argparse.Namespace) -> None:
    from secure3d.dynamics import model_from_spec
    from secure3d.reactive.family_store import FitSettings, fit_checked
    from secure3d.world.scenario import load_scenario

    scenario = load_scenario(path)
    model = model_from_spec(scenario.vehicle, scenario.camera)
    controller = scenario.planner.controller
    settings = FitSettings(
        n_samples=args.n_samples, n_check=args.check, margin=args.margin, dt=args.dt, seed=args.seed
    )
    t0 = time.perf_counter()
    family = fit_checked(model, controller, args.latency, settings)
    out = Path(args.out_dir) / f"{model.name}_{controller}_{scenario.name}.json"
    save_family(family, out)
    print(f"{scenario.name}: fitted and checked in {time.perf_counter() - t0:.1f} s -> {out}")
    print(f"  limits {model.limits}, body radius {model.body_radius} m")
    print(f"  containment check: {family.meta['containment_check']}")
    print(f"  mean volume {family.meta['volume_ratio']:.4f} x closed form")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--family", action="append", choices=FAMILIES, help="fit only these (repeatable)"
    )
    ap.add_argument("--n-samples", type=int, default=20_000, help="fitting manoeuvres per family")
    ap.add_argument(
        "--seed", type=int, default=20_240, help="fitting seed (family i uses seed + 1000 i)"
    )
    ap.add_argument("--check", type=int, default=10_000, help="fresh manoeuvres to check (0: skip)")
    ap.add_argument("--check-seed", type=int, default=777, help="seed of the independent check")
    ap.add_argument("--latency", type=float, default=0.0, help="reaction latency (s)")
    ap.add_argument("--margin", type=float, default=0.01, help="safety inflation (m)")
    ap.add_argument("--dt", type=float, default=0.01, help="integration step (s)")
    ap.add_argument("--body-radius", type=float, default=0.2, help="body radius (m)")
    ap.add_argument("--out-dir", default=str(DATA_DIR), help="where to write the JSON files")
    ap.add_argument(
        "--scenario", action="append", help="fit the family of this scenario's vehicle (repeatable)"
    )
    args = ap.parse_args(argv)
    if args.scenario:
        for path in args.scenario:
            fit_scenario(path, args)
        return 0
    for name in args.family or FAMILIES:
        fit_one(name, args, FAMILIES.index(name))
    return 0


if __name__ == "__main__":
    sys.exit(main())
