"""Limits and field checks of the scenario data model (:mod:`secure3d.world.spec`, which
re-exports them): each check returns the cleaned value or raises
:class:`~secure3d.errors.ScenarioError` as ``"<field>: <problem> (got <value>)"``.
"""

from __future__ import annotations

import math
import re
import reprlib
from numbers import Real

import numpy as np

from secure3d.dynamics import MODELS
from secure3d.errors import ScenarioError
from secure3d.validation import is_int_in, is_real

Vec3 = tuple[float, float, float]

#: Largest world extent we accept along any axis (m). Bigger is almost surely a unit error
#: (millimetres) and would make the voxel map explode.
MAX_WORLD_EXTENT = 2000.0
#: Largest number of obstacles of one kind in a scenario file.
MAX_OBSTACLES = 5000
#: Largest number of voxels the robot's map may span (world volume / resolution^3). 1e9 cells is
#: e.g. 1 km x 1 km x 100 m at 10 cm: beyond that the scenario is a unit error, not a test case.
MAX_MAP_VOXELS = 1e9
#: OctoMap keys are 16 bit, centred on the origin: |coordinate| / resolution must stay below 2^15.
OCTOMAP_KEY_HALF_RANGE = 32768

#: The vehicle models a scenario may name: the dynamics registry's.
VEHICLE_MODELS = tuple(MODELS)
ATTACK_KINDS = ("hide", "phantom", "shift", "stale")


#: A bounded ``repr``: nested containers are shown 3 levels and 4 items deep, so the text (and the
#: time to make it) is bounded even for a YAML alias structure that expands to billions of items.
_REPR = reprlib.Repr()
_REPR.maxlevel, _REPR.maxstring, _REPR.maxother = 3, 80, 80
_REPR.maxlist = _REPR.maxtuple = _REPR.maxdict = _REPR.maxset = _REPR.maxfrozenset = 4


def _short(value: object, limit: int = 60) -> str:
    """A bounded ``repr(value)`` cut to one short line, for error messages."""
    text = " ".join(_REPR.repr(value).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _vec3(value: object, what: str) -> Vec3:
    if isinstance(value, (str, bytes)):
        raise ScenarioError(f"{what}: expected 3 numbers (got {_short(value)})")
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ScenarioError(f"{what}: expected 3 numbers (got {_short(value)})") from None
    if arr.shape != (3,):
        raise ScenarioError(f"{what}: expected 3 numbers (got {_short(value)})")
    if not np.all(np.isfinite(arr)):
        raise ScenarioError(f"{what}: must be finite (got {_short(value)})")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _number(value: object, what: str) -> float:
    if not is_real(value, types=(Real,)):
        raise ScenarioError(f"{what}: expected a number (got {_short(value)})")
    v = float(value)
    if not math.isfinite(v):
        raise ScenarioError(f"{what}: must be finite (got {_short(value)})")
    return v


def _positive(value: object, what: str, *, allow_zero: bool = False) -> float:
    v = _number(value, what)
    if v < 0 or (v == 0 and not allow_zero):
        bound = ">= 0" if allow_zero else "> 0"
        raise ScenarioError(f"{what}: must be {bound} (got {_short(value)})")
    return v


def _integer(value: object, what: str, lo: int, hi: int | None = None) -> int:
    if not is_int_in(value, lo, hi, numpy=True):
        span = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
        raise ScenarioError(f"{what}: must be an integer {span} (got {_short(value)})")
    return int(value)


def _choice(value: object, options: tuple[str, ...], what: str) -> str:
    if value not in options:
        raise ScenarioError(f"{what}: must be one of {', '.join(options)} (got {_short(value)})")
    return str(value)


def _name(value: object, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ScenarioError(f"{what}: must be a non-empty string (got {_short(value)})")
    return value


#: A scenario's name becomes part of output file names (``<name>_secure.rrd``): letters, digits,
#: ``_``, ``-`` and ``.``, not starting with ``.`` (no path separators, no ``..``, no hidden files).
_FILE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9_.-]{0,119}")


def _file_name(value: object, what: str) -> str:
    """``_name`` that is also safe as a file-name stem (see :data:`_FILE_NAME`)."""
    name = _name(value, what)
    if _FILE_NAME.fullmatch(name) is None:
        raise ScenarioError(
            f"{what}: must be 1-120 letters, digits, '_', '-' or '.', not starting with '.'"
            f" (it names output files; got {_short(value)})"
        )
    return name


def _fmt(v: object) -> str:
    """``(1, 2.5, 0)``: a vector printed compactly for summaries."""
    return "(" + ", ".join(f"{float(x):.3g}" for x in np.ravel(v)) + ")"


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"
