"""Speed over time of one or several runs (the paper's speed-profile panel)."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from secure3d.errors import ConfigError, GeometryError
from secure3d.viz.figures import color_for, save_figure

__all__ = ["speed_profile_figure"]


def speed_profile_figure(
    series: Mapping[str, tuple[np.ndarray, np.ndarray]],
    out_path: str | os.PathLike[str],
    *,
    markers: Mapping[str, Sequence[tuple[float, str]]] | None = None,
    speed_limit: float | None = None,
    title: str | None = None,
) -> Path:
    """Speed over time of several runs (e.g. secure vs baseline), saved as an image.

    Parameters
    ----------
    series : mapping label -> (t (T,) float, speed (T,) float)
        Time (s) and speed (m/s) of each run; the legend shows each run's duration.
    out_path : str or Path
        Image file to write (atomically).
    markers : mapping label -> sequence of (t, text), optional
        Events to mark on a run's curve (e.g. ``(2.1, "hidden obstacle seen")``).
    speed_limit : float, optional
        Drawn as a dotted horizontal line (m/s).
    """
    if not series:
        raise ConfigError("series: need at least one (t, speed) series")
    fig = Figure(figsize=(8.0, 3.6))
    ax = fig.add_subplot(1, 1, 1)
    for i, (label, (t, v)) in enumerate(series.items()):
        t = np.asarray(t, dtype=float).reshape(-1)
        v = np.asarray(v, dtype=float).reshape(-1)
        if t.shape != v.shape or len(t) == 0:
            raise GeometryError(
                f"series[{label!r}]: need equal, non-empty t and speed, got {t.shape} and {v.shape}"
            )
        color = color_for(label, i)
        duration = t[-1] - t[0]
        ax.plot(t, v, color=color, linewidth=2.0, label=f"{label} ({duration:.2f} s)")
        for tm, text in (markers or {}).get(label, ()):
            vm = np.interp(tm, t, v)
            ax.plot([tm], [vm], "x", color="red", markersize=10, markeredgewidth=2.5, zorder=5)
            ax.annotate(
                text, (tm, vm), textcoords="offset points", xytext=(6, 8), fontsize=8, color=color
            )
    if speed_limit is not None:
        ax.axhline(speed_limit, color="0.4", linestyle=":", linewidth=1.2, label="speed limit")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("speed (m/s)")
    top = max([float(np.nanmax(np.asarray(v, dtype=float))) for _, v in series.values()] + [0.0])
    top = max(top, speed_limit or 0.0)
    ax.set_ylim(0.0, 1.08 * top if top > 0 else 1.0)
    ax.grid(True, linewidth=0.4, alpha=0.5)
    ax.legend(fontsize=9, frameon=False)
    if title:
        ax.set_title(title)
    return save_figure(fig, out_path)
