"""Hold numpy to its AVX2 kernels, so that plans and flights do not depend on AVX-512.

numpy picks its vector kernels (sin, cos, exp, sorts, reductions) by the CPU's instruction sets
when it is imported. Its AVX-512 kernels give other last bits than its AVX2 ones, and the planner
amplifies last bits: on an AMD EPYC with AVX-512 the pinned planar plan moved by 2e-6 relative and
``warehouse_survey``'s secure flight reached its goal at 21.30 s instead of 9.09 s, on unchanged
code (``benchmarks/results/closed_loop_session38.md``). So ``import secure3d`` holds numpy to its
x86-64-v3 (AVX2) kernels at most, and the same code then gives the same plans on CPUs with and
without AVX-512 (on a CPU without AVX-512 the variable changes nothing). It can do so only when
numpy is not imported yet: numpy reads ``NPY_DISABLE_CPU_FEATURES`` once, at its import. The
variable stays in the environment, so the processes secure3d starts (campaign workers, a local
Ray, benchmarks' fresh runs) hold numpy the same way; Ray actors on a cluster get it through their
``runtime_env`` (:func:`secure3d.simulation.campaign_ray.actor_env`).

``$SECURE3D_NUMPY_KERNELS`` chooses:

- ``portable`` (the default): as above, where numpy is not imported yet, is a release whose
  feature names this was checked with (2.4 and later: names it does not know it ignores), and the
  user has not set ``NPY_DISABLE_CPU_FEATURES`` themselves (theirs is kept);
- ``native``: leave numpy alone (its fastest kernels for this CPU; outcomes may then differ on
  another CPU).

:func:`numpy_kernels` says what happened in this process.

This module imports nothing that imports numpy: it runs first in ``secure3d/__init__.py``.
"""

from __future__ import annotations

import os
import sys

from secure3d.errors import ConfigError

__all__ = ["DISABLED_FEATURES", "ENV", "NUMPY_ENV", "hold_before_numpy", "numpy_kernels"]

#: The environment variable choosing ``portable`` or ``native`` kernels.
ENV = "SECURE3D_NUMPY_KERNELS"
#: numpy's own variable, read at its import.
NUMPY_ENV = "NPY_DISABLE_CPU_FEATURES"
#: numpy's dispatch targets above x86-64-v3 (AVX2): numpy 2.4 groups AVX-512 into these three.
DISABLED_FEATURES = ("X86_V4", "AVX512_ICL", "AVX512_SPR")
#: The first numpy release whose dispatch targets are :data:`DISABLED_FEATURES`.
CHECKED_FROM = (2, 4)

_MODES = ("portable", "native")
_state: dict[str, str] = {"mode": "native", "reason": "hold_before_numpy was not called"}


def _numpy_release() -> tuple[int, ...] | None:
    """The installed numpy's (major, minor), read from its ``version.py`` without importing numpy
    (``importlib.metadata`` costs more than the rest of ``import secure3d``)."""
    import importlib.util
    import re
    from pathlib import Path

    try:
        spec = importlib.util.find_spec("numpy")
        if spec is None or spec.origin is None:
            return None
        text = (Path(spec.origin).parent / "version.py").read_text(encoding="utf-8")
    except (ImportError, OSError, ValueError):
        return None
    found = re.search(r"^(?:full_)?version\s*[:=][^'\"]*['\"](\d+)\.(\d+)", text, re.MULTILINE)
    return (int(found.group(1)), int(found.group(2))) if found else None


def hold_before_numpy() -> dict[str, str]:
    """Set ``NPY_DISABLE_CPU_FEATURES`` for numpy's AVX2 kernels where it can still act (module
    docstring). Returns ``{"mode": "portable" | "native", "reason": ...}`` (also kept for
    :func:`numpy_kernels`). Raises :class:`~secure3d.errors.ConfigError` naming :data:`ENV` for a
    value it does not know.
    """
    choice = os.environ.get(ENV, "portable").strip().lower() or "portable"
    if choice not in _MODES:
        raise ConfigError(f"{ENV}: must be one of {', '.join(_MODES)}, got {os.environ.get(ENV)!r}")
    if choice == "native":
        return _record("native", f"{ENV}=native")
    if NUMPY_ENV in os.environ:
        return _record("native", f"{NUMPY_ENV} is set by the user ({os.environ[NUMPY_ENV]!r})")
    if "numpy" in sys.modules:
        return _record("native", "numpy was imported before secure3d")
    release = _numpy_release()
    if release is None or release < CHECKED_FROM:
        found = "not found" if release is None else ".".join(map(str, release))
        return _record("native", f"numpy {found}: its feature names were not checked")
    os.environ[NUMPY_ENV] = " ".join(DISABLED_FEATURES)
    return _record("portable", f"{NUMPY_ENV}={os.environ[NUMPY_ENV]}")


def _record(mode: str, reason: str) -> dict[str, str]:
    _state.update(mode=mode, reason=reason)
    return dict(_state)


def numpy_kernels() -> dict[str, object]:
    """What this process's numpy runs: ``mode`` (``portable`` when secure3d held it to AVX2,
    ``native`` otherwise), ``reason``, and ``dispatch``: the dispatch targets numpy uses on this
    CPU (imports numpy)."""
    import numpy as np

    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:  # numpy 1.x
        from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    active = [name for name in __cpu_dispatch__ if __cpu_features__.get(name)]
    return {**_state, "numpy": np.__version__, "dispatch": active}
