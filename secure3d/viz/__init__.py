"""Views of a run: Rerun replays (:mod:`~secure3d.viz.rerun_log`) and matplotlib figures
(:mod:`~secure3d.viz.figures`). They only consume results; nothing here feeds back into planning.

Names are exported lazily: importing this package loads neither Rerun nor matplotlib.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "RerunRecorder": "secure3d.viz.rerun_log",
    "recording_id": "secure3d.viz.rerun_log",
    "top_down_figure": "secure3d.viz.figures",
    "draw_top_down": "secure3d.viz.figures",
    "speed_profile_figure": "secure3d.viz.speed_figure",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'secure3d.viz' has no attribute {name!r}") from None
    return getattr(importlib.import_module(module), name)
