"""Helpers shared by the benchmark scripts: timing, medians, markdown tables, atomic result files.

Benchmarks are scripts, not library code: nothing here is imported by ``secure3d``.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
_CPP_LOCATION = re.compile(r"^\S*\.(?:cpp|hpp|h|cc):\d+:\s*")


@dataclass(frozen=True)
class Timed:
    """Outcome of :func:`timed`: the return value (or the exception), wall and CPU seconds."""

    value: Any
    error: BaseException | None
    wall: float
    cpu: float


def timed(fn: Callable[[], Any]) -> Timed:
    """Call ``fn()`` and measure wall (``perf_counter``) and process CPU time (``process_time``).

    An exception is caught and returned in ``error``, so one failing case cannot end a benchmark.
    """
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    try:
        value, error = fn(), None
    except Exception as exc:  # noqa: BLE001 - the benchmark reports every failure, it never crashes
        value, error = None, exc
    return Timed(value, error, time.perf_counter() - t_wall, time.process_time() - t_cpu)


def error_text(exc: BaseException, limit: int = 300) -> str:
    """``Type: message`` on one line, shortened to ``limit`` characters.

    CasADi's errors span several lines, each prefixed by a C++ source location
    (``.../fatrop_interface.cpp:477: ``); the prefixes go and the lines are joined with `` / ``.
    """
    lines = [_CPP_LOCATION.sub("", ln).strip() for ln in str(exc).strip().splitlines()]
    text = f"{type(exc).__name__}: " + " / ".join(ln for ln in lines if ln)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def nanmedian(values: Sequence[float | None]) -> float:
    """Median of the finite entries (None and NaN skipped); NaN when there are none."""
    arr = np.array([np.nan if v is None else v for v in values], dtype=float)
    arr = arr[np.isfinite(arr)]
    return float(np.median(arr)) if arr.size else math.nan


@contextlib.contextmanager
def captured_native_output() -> Iterator[list[str]]:
    """Send file descriptors 1 and 2 to a temporary file for the duration of the block.

    CasADi's C++ plugins (fatrop's structure detection, for instance) write straight to the file
    descriptors, thousands of lines per build, which would bury the tables and the progress bar.
    The yielded list receives the captured lines when the block ends.
    """
    lines: list[str] = []
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    with tempfile.TemporaryFile(mode="w+b") as sink:
        try:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            yield lines
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved:
                os.close(fd)
            sink.seek(0)
            lines.extend(sink.read().decode("utf-8", "replace").splitlines())


def fmt(value: float | None, digits: int = 2, scale: float = 1.0, empty: str = "—") -> str:
    """A number for a table cell: ``empty`` for None/NaN, else ``value * scale`` rounded."""
    if value is None or not math.isfinite(value):
        return empty
    return f"{value * scale:.{digits}f}"


def markdown_table(
    headers: Sequence[str], rows: Sequence[Sequence[object]], right: Sequence[bool] | None = None
) -> str:
    """A GitHub markdown table with padded columns.

    Parameters
    ----------
    headers : column titles.
    rows : cells (converted with ``str``), one sequence per row, as long as ``headers``.
    right : per column, True to right-align (default: every column but the first).
    """
    right = [i > 0 for i in range(len(headers))] if right is None else list(right)
    cells = [[str(c) for c in headers]] + [[str(c) for c in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]

    def line(row: list[str]) -> str:
        parts = [
            c.rjust(w) if r else c.ljust(w) for c, w, r in zip(row, widths, right, strict=True)
        ]
        return "| " + " | ".join(parts) + " |"

    rule = (
        "|"
        + "|".join(
            ("-" * (w + 1) + ":") if r else ("-" * (w + 2))
            for w, r in zip(widths, right, strict=True)
        )
        + "|"
    )
    return "\n".join([line(cells[0]), rule, *(line(r) for r in cells[1:])])


def _json_default(obj: object) -> object:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def _finite_only(obj: object) -> object:
    """NaN and infinities become None (strict JSON has no literal for them)."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {k: _finite_only(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_only(v) for v in obj]
    return obj


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` to ``path`` (its folder created if needed) with the package's one atomic
    writer (:func:`secure3d.outputs.atomic_write_text`): a reader never sees a half-written file
    and an interrupted run leaves the old one."""
    from secure3d import outputs

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return outputs.atomic_write_text(path, text)


def atomic_write_json(path: str | os.PathLike[str], data: object) -> Path:
    """:func:`atomic_write_text` of ``data`` as strict JSON (numpy values converted, NaN: null)."""
    plain = json.loads(json.dumps(data, default=_json_default))
    return atomic_write_text(
        path, json.dumps(_finite_only(plain), indent=1, allow_nan=False) + "\n"
    )


def python_json(code: str, args: Sequence[str], cwd: Path, env: dict[str, str]) -> dict:
    """Run ``code`` (``python -c``) with ``args`` in a new process and read the JSON object on its
    last line of output; ``{"error": last line of stderr}`` if it failed."""
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, "-c", code, *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    if done.returncode:
        return {"error": done.stderr.strip().splitlines()[-1] if done.stderr else "failed"}
    return json.loads(done.stdout.strip().splitlines()[-1])


def machine_info() -> dict[str, object]:
    """What the numbers depend on: host, CPU count, load, versions, and the commit benchmarked."""
    import casadi

    try:
        commit = subprocess.run(
            ["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=True,
        ).stdout.strip()
        dirty = bool(
            subprocess.run(
                ["git", "-C", str(REPO), "status", "--porcelain", "--untracked-files=no"],
                capture_output=True,
                text=True,
                timeout=10,
                check=True,
            ).stdout.strip()
        )
    except (OSError, subprocess.SubprocessError):
        commit, dirty = None, None
    return {
        "host": platform.node(),
        "cpus": os.cpu_count(),
        "load_avg": list(os.getloadavg()),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "casadi": casadi.__version__,
        "commit": commit,
        "dirty": dirty,
        "date": time.strftime("%Y-%m-%d %H:%M:%S %z"),
    }
