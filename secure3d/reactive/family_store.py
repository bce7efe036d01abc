"""Where a vehicle's fitted reactive-set family comes from, for any limits.

:func:`family_for` (what the planner calls) looks, in order, for

1. a family shipped in ``secure3d/reactive/data`` (fitted for the default limits of each model);
2. a family in the user's cache (:func:`cache_dir`), fitted earlier on this machine for exactly
   this model, limits, body radius, controller settings and latency (:func:`family_key`);
3. otherwise it fits one now (:func:`fit_checked`, a progress bar on stderr, once per setting)
   and stores it in the cache.

A family fitted on demand is used only after :func:`~secure3d.reactive.reactive_set.check_containment`
found every body ball of every one of ``FitSettings.n_check`` fresh manoeuvres (independent seed)
inside its ellipsoid; otherwise the margin is raised and the fit repeated, and after
``FitSettings.max_attempts`` failures :class:`~secure3d.errors.ConfigError` says so. There is no
silent fallback to the closed form: ``reactive_family: closed_form`` asks for it explicitly.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from secure3d.dynamics.base import VehicleModel
from secure3d.errors import ConfigError
from secure3d.outputs import atomic_write_text
from secure3d.reactive.fitting import fit_family
from secure3d.reactive.reactive_set import (
    CONTROLLERS,
    FAMILY_KINDS,
    FORMAT_VERSION,
    FittedFamily,
    ReactiveSetFamily,
    check_containment,
    closed_form_family,
)
from secure3d.validation import is_int_in

__all__ = [
    "DATA_DIR",
    "FitSettings",
    "cache_dir",
    "default_controller",
    "family_for",
    "family_key",
    "fit_checked",
    "load_family",
    "load_family_file",
    "save_family",
]

log = logging.getLogger("secure3d.reactive")

DATA_DIR = Path(__file__).resolve().parent / "data"
#: Environment variable naming the cache root (default ``$XDG_CACHE_HOME/secure3d`` or
#: ``~/.cache/secure3d``); families go to its ``reactive/`` folder.
CACHE_ENV = "SECURE3D_CACHE_DIR"
#: Fit stages reported to the progress bar per attempt (see :func:`fit_family`'s ``progress``).
_FIT_STAGES = 6


@dataclass(frozen=True)
class FitSettings:
    """How a family is fitted on demand and checked before use.

    Attributes
    ----------
    n_samples : fitting manoeuvres (a second sample as large validates the inflation).
    n_check : fresh manoeuvres, from ``check_seed``, every one of which must be contained.
    margin : isotropic safety inflation (m) of the first attempt.
    dt : integration step (s) of the simulated manoeuvres.
    seed, check_seed : seeds of the fit and of the independent check.
    max_attempts : fits tried, the margin raised after each failed check.
    """

    n_samples: int = 8_000
    n_check: int = 10_000
    margin: float = 0.01
    dt: float = 0.01
    seed: int = 20_240
    check_seed: int = 777
    max_attempts: int = 3

    def __post_init__(self) -> None:
        for name, low in (("n_samples", 100), ("n_check", 100), ("max_attempts", 1)):
            value = getattr(self, name)
            if not is_int_in(value, low):
                raise ConfigError(f"FitSettings.{name}: must be an integer >= {low}, got {value!r}")
        for name in ("seed", "check_seed"):
            value = getattr(self, name)
            if not is_int_in(value, 0):
                raise ConfigError(
                    f"FitSettings.{name}: must be a non-negative integer, got {value!r}"
                )
        if not (math.isfinite(self.margin) and 0 <= self.margin <= 1):
            raise ConfigError(f"FitSettings.margin: must be in [0, 1] m, got {self.margin!r}")
        if not (math.isfinite(self.dt) and 1e-4 <= self.dt <= 0.1):
            raise ConfigError(f"FitSettings.dt: must be in [1e-4, 0.1] s, got {self.dt!r}")


def cache_dir() -> Path:
    """The folder of families fitted on demand: ``<cache root>/reactive`` (see :data:`CACHE_ENV`)."""
    root = os.environ.get(CACHE_ENV)
    if not root:
        xdg = os.environ.get("XDG_CACHE_HOME")
        root = str(Path(xdg) / "secure3d") if xdg else str(Path.home() / ".cache" / "secure3d")
    return Path(root).expanduser() / "reactive"


def default_controller(
    model: VehicleModel, controller: str = "braking", latency: float = 0.0
) -> Any:
    """The reactive controller the planner pairs with a family (default settings)."""
    from secure3d.reactive.controllers import BrakingController, MPCReactiveController

    if controller == "braking":
        return BrakingController(model, latency)
    if controller == "mpc":
        return MPCReactiveController(model, latency=latency)
    raise ConfigError(f"controller: must be one of {CONTROLLERS}, got {controller!r}")


def family_key(model: VehicleModel, controller: str, latency: float, settings: FitSettings) -> str:
    """Hex digest of everything a fitted family depends on.

    Model name, limits, body radius, controller name and settings (gains, MPC weights), latency,
    the fit settings and the file format: two settings with the same key fly the same manoeuvres.
    """
    desc = {
        "format": FORMAT_VERSION,
        "model": model.name,
        "limits": dataclasses.asdict(model.limits),
        "body_radius": model.body_radius,
        "controller": controller,
        "controller_config": default_controller(model, controller, latency).config(),
        "latency": float(latency),
        "fit": dataclasses.asdict(settings),
    }
    text = json.dumps(desc, sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()


def save_family(family: FittedFamily, path: str | os.PathLike[str]) -> Path:
    """Write a fitted family as JSON, atomically (:func:`secure3d.outputs.atomic_write_text`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_text(path, json.dumps(family.to_dict(), indent=1, sort_keys=True) + "\n")


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, str) or isinstance(b, str):
        return a == b
    return a is not None and b is not None and math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-12)


def _mismatch(
    data: dict[str, Any], model: VehicleModel, controller: str, latency: float
) -> str | None:
    """Why the stored family does not apply to ``model`` (None if it does)."""
    if data.get("model") != model.name:
        return f"model: stored {data.get('model')!r}, wanted {model.name!r}"
    if data.get("controller") != controller:
        return f"controller: stored {data.get('controller')!r}, wanted {controller!r}"
    stored = data.get("limits", {})
    mine = dataclasses.asdict(model.limits)
    for key in sorted(set(stored) | set(mine)):
        if not _same(stored.get(key), mine.get(key)):
            return f"limits.{key}: stored {stored.get(key)!r}, model has {mine.get(key)!r}"
    # A family that contains a bigger body ball also contains a smaller one.
    if model.body_radius > float(data.get("body_radius", -1.0)) + 1e-12:
        return f"body_radius: stored {data.get('body_radius')!r} m < model's {model.body_radius} m"
    if not math.isclose(float(data.get("latency", -1.0)), latency, abs_tol=1e-12):
        return f"latency: stored {data.get('latency')!r} s, wanted {latency} s"
    # Gains and MPC weights shape the manoeuvres: a family fitted for others does not apply.
    wanted = json.loads(json.dumps(default_controller(model, controller, latency).config()))
    stored_cfg = data.get("meta", {}).get("controller_config")
    if stored_cfg != wanted:
        return f"controller settings: stored {stored_cfg!r}, default controller has {wanted!r}"
    return None


def load_family_file(
    path: str | os.PathLike[str],
    model: VehicleModel,
    controller: str = "braking",
    latency: float = 0.0,
) -> FittedFamily:
    """Read one fitted-family JSON for ``model``.

    Raises
    ------
    ConfigError
        The file is not a fitted family, or it was fitted for another model, controller, limits,
        latency or a smaller body radius (the message names the field and both values).
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"reactive family file {path}: unreadable ({exc})") from None
    if (
        not isinstance(data, dict)
        or data.get("format") != FORMAT_VERSION
        or data.get("kind") != "fitted"
    ):
        raise ConfigError(
            f"reactive family file {path}: not a fitted family of format {FORMAT_VERSION}"
        )
    why = _mismatch(data, model, controller, latency)
    if why is not None:
        raise ConfigError(f"reactive family file {path.name}: fitted for different settings: {why}")
    co = data["coefficients"]
    return FittedFamily(
        model,
        controller,
        float(data["latency"]),
        data["feature_map"],
        co["centre"],
        co["beta"],
        co["gamma"],
        co["eta"],
        meta={
            **data.get("meta", {}),
            "source": path.name,
            "fitted_body_radius": data["body_radius"],
        },
    )


class _Bar:
    """A tqdm bar over the fit's stages (silent when ``enabled`` is false or stderr is no TTY)."""

    def __init__(self, label: str, attempts: int, enabled: bool):
        from tqdm import tqdm

        self._bar = tqdm(
            total=(_FIT_STAGES + 1) * attempts,
            desc=label,
            unit="step",
            disable=None if enabled else True,
            leave=False,
        )

    def __call__(self, stage: str) -> None:
        self._bar.set_postfix_str(stage, refresh=False)
        self._bar.update(1)

    def close(self) -> None:
        self._bar.close()


def fit_checked(
    model: VehicleModel,
    controller: str = "braking",
    latency: float = 0.0,
    settings: FitSettings | None = None,
    progress: bool = True,
    *,
    fit: Callable[..., FittedFamily] = fit_family,
) -> FittedFamily:
    """Fit a family for ``model`` and return it only once it contains every fresh manoeuvre.

    Each attempt fits on ``settings.n_samples`` manoeuvres, then checks ``settings.n_check``
    manoeuvres from the independent ``check_seed``; a failed check raises the margin by twice the
    worst excess (at least 5 mm) and refits from the next seed. ``fit`` is the fitting function
    (:func:`~secure3d.reactive.fitting.fit_family`; tests pass a deliberately poor one).

    Raises
    ------
    ConfigError
        No attempt passed the check.
    """
    settings = FitSettings() if settings is None else settings
    ctrl = default_controller(model, controller, latency)
    bar = _Bar(f"fitting reactive set {model.name}/{controller}", settings.max_attempts, progress)
    margin, excess = settings.margin, float("nan")
    try:
        for attempt in range(settings.max_attempts):
            seed = settings.seed + 1000 * attempt
            fam = fit(
                model,
                ctrl,
                settings.n_samples,
                np.random.default_rng(seed),
                margin=margin,
                dt=settings.dt,
                seed=seed,
                progress=bar,
            )
            rng = np.random.default_rng(settings.check_seed)
            report = check_containment(fam, ctrl, settings.n_check, rng, dt=settings.dt)
            bar("check")
            if report.passed:
                fam.meta["containment_check"] = {
                    "n_manoeuvres": report.n_manoeuvres,
                    "n_points": report.n_points,
                    "worst_excess": report.worst_excess,
                    "seed": settings.check_seed,
                }
                return fam
            excess = report.worst_excess
            log.info("reactive-set fit attempt %d failed its check: %s", attempt + 1, report)
            margin += max(2.0 * excess, 0.005)
    finally:
        bar.close()
    raise ConfigError(
        f"no fitted {controller!r} reactive family for this {model.name}: {settings.max_attempts} "
        f"fits failed the containment check (worst excess {excess:+.4f} m); "
        "set planner.reactive_family: closed_form to use the closed form"
    )


def _shipped(model: VehicleModel, controller: str, latency: float) -> FittedFamily | None:
    for path in sorted(DATA_DIR.glob(f"{model.name}_{controller}*.json")):
        try:
            return load_family_file(path, model, controller, latency)
        except ConfigError:
            continue
    return None


def _cached(
    path: Path, model: VehicleModel, controller: str, latency: float
) -> FittedFamily | None:
    if not path.is_file():
        return None
    try:
        return load_family_file(path, model, controller, latency)
    except ConfigError as exc:
        log.warning("ignoring cached reactive family: %s", exc)
        return None


def load_family(
    model: VehicleModel,
    controller: str = "braking",
    kind: str = "fitted",
    latency: float = 0.0,
    settings: FitSettings | None = None,
    progress: bool = True,
    *,
    fit: Callable[..., FittedFamily] = fit_family,
) -> ReactiveSetFamily:
    """The reactive-set family for ``model`` and ``controller`` (see the module docstring).

    ``kind="closed_form"`` returns :func:`~secure3d.reactive.reactive_set.closed_form_family`
    (braking only). ``kind="fitted"`` returns a shipped family, a cached one, or one fitted now
    and checked (:func:`fit_checked`, with ``fit``), which is then cached (a cache that cannot be written is
    reported and skipped).
    """
    if kind not in FAMILY_KINDS:
        raise ConfigError(f"reactive_family: must be one of {FAMILY_KINDS}, got {kind!r}")
    if controller not in CONTROLLERS:
        raise ConfigError(f"controller: must be one of {CONTROLLERS}, got {controller!r}")
    if kind == "closed_form":
        if controller != "braking":
            raise ConfigError(
                "reactive_family 'closed_form' exists for the braking controller only, "
                f"not {controller!r}"
            )
        return closed_form_family(model, latency)
    found = _shipped(model, controller, latency)
    if found is not None:
        return found
    settings = FitSettings() if settings is None else settings
    key = family_key(model, controller, latency, settings)
    path = cache_dir() / f"{model.name}_{controller}_{key[:20]}.json"
    found = _cached(path, model, controller, latency)
    if found is not None:
        return found
    log.info(
        "no fitted %s/%s reactive family for these limits yet: fitting one (once; cached at %s)",
        model.name,
        controller,
        path,
    )
    fam = fit_checked(model, controller, latency, settings, progress, fit=fit)
    try:
        save_family(fam, path)
    except OSError as exc:
        log.warning("could not cache the fitted reactive family at %s: %s", path, exc)
    return fam


def family_for(
    model: VehicleModel, controller: str = "braking", kind: str = "fitted", latency: float = 0.0
) -> ReactiveSetFamily:
    """The reactive-set family the planner should use (see :func:`load_family`)."""
    return load_family(model, controller, kind, latency)
