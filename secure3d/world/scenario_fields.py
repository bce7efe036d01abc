"""Reading a scenario file's fields: the strict YAML loader (duplicate and non-string keys
refused, size and alias-expansion limits) and one reader per field type, each returning the value
or raising :class:`_FieldError` at the field's path. :mod:`secure3d.world.scenario` builds the
sections from them (and re-exports the limits).
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import types
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Literal, Union, get_args, get_origin, get_type_hints

import yaml

from secure3d.errors import ScenarioError
from secure3d.validation import is_int, is_real
from secure3d.world import spec
from secure3d.world.spec import (
    MAX_OBSTACLES,
)

#: Largest scenario file we parse (bytes). Real scenarios are a few kB; anything near 1 MB is a
#: mistake (or an attempt to make the YAML parser work hard).
MAX_SCENARIO_BYTES = 1_000_000
#: Most values a scenario may hold once its YAML aliases are expanded. Aliases share one object,
#: so a few hundred bytes can stand for billions of values (an "alias bomb"), which any later
#: walk over them (validation, an error message, a copy) would expand.
MAX_EXPANDED_VALUES = 100_000


class _FieldError(Exception):
    """A problem at one field path; turned into a ScenarioError with the file name prefixed."""

    def __init__(self, path: str, problem: str, value: object = dataclasses.MISSING) -> None:
        self.path, self.problem, self.value = path, problem, value
        super().__init__(self.line())

    def line(self) -> str:
        got = "" if self.value is dataclasses.MISSING else f" (got {spec._short(self.value)})"
        return f"{self.path}: {self.problem}{got}"


# --------------------------------------------------------------------------------------------
# YAML reading
# --------------------------------------------------------------------------------------------


class _StrictLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # type: ignore[misc]
    """SafeLoader that refuses duplicate and non-string mapping keys (PyYAML keeps the last);
    libyaml's parser when PyYAML has it (5x faster)."""


def _construct_mapping(loader: _StrictLoader, node: yaml.MappingNode) -> dict[str, Any]:
    loader.flatten_mapping(node)
    out: dict[str, Any] = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if not isinstance(key, str):
            raise yaml.constructor.ConstructorError(
                None, None, f"mapping keys must be strings (got {key!r})", key_node.start_mark
            )
        if key in out:
            raise yaml.constructor.ConstructorError(
                None, None, f"duplicate key {key!r}", key_node.start_mark
            )
        out[key] = loader.construct_object(value_node, deep=True)
    return out


_StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def _read_yaml(path: Path, label: str) -> object:
    if not path.exists():
        raise ScenarioError(f"{label}: no such file")
    if not path.is_file():
        raise ScenarioError(f"{label}: not a regular file")
    try:
        size = path.stat().st_size
        if size > MAX_SCENARIO_BYTES:
            raise ScenarioError(
                f"{label}: scenario files must be at most {MAX_SCENARIO_BYTES} bytes"
                f" (got {size} bytes)"
            )
        with path.open("rb") as fh:
            raw = fh.read(MAX_SCENARIO_BYTES + 1)
    except OSError as exc:
        raise ScenarioError(f"{label}: cannot read: {exc.strerror or exc}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ScenarioError(f"{label}: not UTF-8 text (bad byte at offset {exc.start})") from None
    try:
        data = yaml.load(text, Loader=_StrictLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark else ""
        problem = " ".join(str(exc.problem or exc.context or "invalid YAML").split())
        raise ScenarioError(f"{label}: {where}YAML error: {problem}") from None
    except (yaml.YAMLError, RecursionError, ValueError) as exc:  # ValueError: int() limits
        detail = " ".join(str(exc).split())[:120] or type(exc).__name__
        raise ScenarioError(f"{label}: YAML error: {detail}") from None
    why = _expansion_problem(data, MAX_EXPANDED_VALUES)
    if why is not None:
        raise ScenarioError(f"{label}: {why}")
    return data


def _expansion_problem(data: object, limit: int) -> str | None:
    """Why ``data`` is unsafe to walk: more than ``limit`` values once aliases are expanded, or
    an alias that contains itself. Counts each shared object once (memo by id), so the check
    costs the size of the file, not of the expansion."""
    sizes: dict[int, int] = {}
    stack: list[tuple[object, bool]] = [(data, False)]
    open_: set[int] = set()
    while stack:
        node, done = stack.pop()
        if not isinstance(node, (dict, list)):
            continue
        key = id(node)
        children = list(node.keys()) + list(node.values()) if isinstance(node, dict) else node
        if done:
            open_.discard(key)
            total = 1 + sum(sizes.get(id(c), 1) for c in children)
            sizes[key] = total
            if total > limit:
                return f"too many values once YAML aliases are expanded (over {limit})"
            continue
        if key in sizes:
            continue
        if key in open_:
            return "a YAML alias refers to a value that contains it"
        open_.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in children if isinstance(c, (dict, list)))
    return None


# --------------------------------------------------------------------------------------------
# Typed field readers (each raises _FieldError with the field path)
# --------------------------------------------------------------------------------------------


def _as_mapping(value: object, path: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _FieldError(path, "expected a mapping (key: value, ...)", value)
    return value


def _as_list(value: object, path: str, limit: int = MAX_OBSTACLES) -> list[Any]:
    if value is None:
        return []
    if not isinstance(value, list):
        raise _FieldError(path, "expected a list", value)
    if len(value) > limit:
        raise _FieldError(path, f"at most {limit} entries allowed", f"{len(value)} entries")
    return value


def _check_keys(
    data: Mapping[str, Any], allowed: tuple[str, ...], required: tuple[str, ...], path: str
) -> None:
    prefix = f"{path}." if path else ""
    for key in data:
        if key not in allowed:
            close = difflib.get_close_matches(key, allowed, n=1)
            hint = f"did you mean {close[0]!r}? " if close else ""
            # a key with line breaks or edge blanks is quoted: the error stays one readable line
            plain = isinstance(key, str) and key.isprintable() and key == key.strip() != ""
            raise _FieldError(
                f"{prefix}{key if plain else repr(key)}",
                f"unknown key; {hint}allowed keys: {', '.join(sorted(allowed))}",
            )
    for key in required:
        if key not in data:
            raise _FieldError(f"{prefix}{key}", "missing required field")


def _as_float(value: object, path: str) -> float:
    if not is_real(value):
        hint = ""
        if isinstance(value, str):
            try:
                float(value)
                hint = " (YAML 1.1 reads exponents without a dot as text: write 1.0e3)"
            except ValueError:
                pass
        raise _FieldError(path, f"expected a number{hint}", value)
    if not _finite(value):
        raise _FieldError(path, "must be a finite number", value)
    return float(value)


def _finite(value: int | float) -> bool:
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond the float range
        return False


def _as_int(value: object, path: str) -> int:
    if not is_int(value):
        raise _FieldError(path, "expected an integer", value)
    return value


def _as_bool(value: object, path: str) -> bool:
    if not isinstance(value, bool):
        raise _FieldError(path, "expected true or false", value)
    return value


def _as_str(value: object, path: str) -> str:
    if not isinstance(value, str):
        raise _FieldError(path, "expected a string", value)
    return value


def _as_name(value: object, path: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise _FieldError(path, "expected a non-empty name", value)
    return value


def _as_vec3(value: object, path: str) -> tuple[float, float, float]:
    if not isinstance(value, list) or len(value) != 3:
        raise _FieldError(path, "expected a list of 3 numbers", value)
    for i, x in enumerate(value):
        if not is_real(x):
            raise _FieldError(f"{path}[{i}]", "expected a number", x)
        if not _finite(x):
            raise _FieldError(path, "must be finite", value)
    return (float(value[0]), float(value[1]), float(value[2]))


def _as_limits(value: object, path: str) -> dict[str, float]:
    data = _as_mapping(value if value is not None else {}, path)
    return {k: _as_float(v, f"{path}.{k}") for k, v in data.items()}


def _reader(hint: object) -> Callable[[object, str], object]:
    """Map a dataclass field's type hint to the reader that checks a YAML value against it."""
    if hint is int:
        return _as_int
    if hint is float:
        return _as_float
    if hint is str:
        return _as_str
    if hint is bool:
        return _as_bool
    if hint == spec.Vec3:
        return _as_vec3
    origin, args = get_origin(hint), get_args(hint)
    if origin is Literal:

        def read_choice(value: object, path: str) -> object:
            if value not in args:
                raise _FieldError(path, f"must be one of {', '.join(map(str, args))}", value)
            return value

        return read_choice
    if origin in (Union, types.UnionType) and type(None) in args:
        (inner,) = [a for a in args if a is not type(None)]
        read = _reader(inner)
        return lambda value, path: None if value is None else read(value, path)
    if origin is Mapping:
        return _as_limits
    if origin is tuple and args == (float, Ellipsis):
        return lambda value, path: tuple(
            _as_float(v, f"{path}[{i}]") for i, v in enumerate(_as_list(value, path, 16))
        )
    raise TypeError(f"no YAML reader for type hint {hint!r}")  # a new spec field needs one


def _flat_section(cls: type, data: object, path: str) -> dict[str, Any]:
    """Check a section whose keys are exactly the fields of dataclass ``cls``; return kwargs."""
    data = _as_mapping(data if data is not None else {}, path)
    fields = dataclasses.fields(cls)
    hints = get_type_hints(cls, vars(spec))
    required = tuple(
        f.name
        for f in fields
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    )
    _check_keys(data, tuple(f.name for f in fields), required, path)
    return {k: _reader(hints[k])(v, f"{path}.{k}") for k, v in data.items()}
