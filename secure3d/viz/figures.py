"""Matplotlib figures of a run: the paper-style top-down view and speed profiles.

The top-down view follows the paper's figures (Ivanov & Campbell, Figs. BasePlanner / Gplanner):
known obstacles filled, the obstacle the server hid in black, the planned path dashed and the
realised one solid, the reactive sets S_r(x) at the plan nodes as ellipses (eq. ReactEllipse; the
xy shadow of each 3D ellipsoid), the detection point as a red X, and camera frusta as translucent
wedges. Obstacles the server invented (phantoms) or moved are outlined dashed where it claims them.

Figures are built on a :class:`matplotlib.figure.Figure` (no pyplot state, no GUI backend) and
written atomically: a temporary file in the target folder is renamed onto ``out_path``, so an
interrupted run never leaves a truncated PNG.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import EllipseCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Polygon, Rectangle
from scipy.spatial import ConvexHull, QhullError

from secure3d.errors import ConfigError
from secure3d.outputs import atomic_output
from secure3d.validation import is_int_in
from secure3d.world.spec import Bounds, Box, MeshObstacle

#: Colours by planner label; other labels cycle through matplotlib's default palette.
PLANNER_COLORS = {"secure": "tab:blue", "baseline": "tab:orange"}
KNOWN_COLOR = "firebrick"
HIDDEN_COLOR = "black"
PHANTOM_COLOR = "darkmagenta"
FRUSTUM_COLOR = "limegreen"
_CYCLE = ("tab:green", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan")
_DPI = 150


def save_figure(fig: Figure, out_path: str | os.PathLike[str]) -> Path:
    """Write ``fig`` to ``out_path`` atomically (:func:`secure3d.outputs.atomic_output`).

    The format follows the suffix of ``out_path`` (``.png`` for the project's figures).
    """
    out = Path(out_path)
    if not out.parent.is_dir():
        raise ConfigError(f"out_path: folder {str(out.parent)!r} does not exist")
    fmt = out.suffix.lstrip(".").lower() or "png"
    with atomic_output(out) as fh:
        fig.savefig(fh, format=fmt, dpi=_DPI, bbox_inches="tight")
    return out


def ellipse_shadows(shapes: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """xy projections of ellipsoids ``E = {c + M z : |z| <= 1}`` (paper eq. ReactEllipse).

    The shadow of E on the xy plane is the ellipse ``{c_xy + P M z}`` with ``P = [I_2 0]``, i.e.
    the ellipse of shape matrix ``S = P M M^T P^T``, the top-left 2x2 block of ``M M^T``.

    Parameters
    ----------
    shapes : (K, 3, 3) float

    Returns
    -------
    widths, heights : (K,) float
        Full axis lengths ``2 sqrt(eig(S))`` (major first).
    angles : (K,) float
        Angle of the major axis from the x axis (degrees).
    """
    M = np.asarray(shapes, dtype=float).reshape(-1, 3, 3)
    S = (M @ np.swapaxes(M, -1, -2))[:, :2, :2]
    lam, V = np.linalg.eigh(S)  # ascending
    lam = np.clip(lam, 0.0, None)
    major = V[:, :, 1]
    angles = np.degrees(np.arctan2(major[:, 1], major[:, 0]))
    return 2 * np.sqrt(lam[:, 1]), 2 * np.sqrt(lam[:, 0]), angles


def color_for(label: str, index: int) -> str:
    for key, color in PLANNER_COLORS.items():
        if key in label.lower():
            return color
    return _CYCLE[index % len(_CYCLE)]


def _footprint(o: Box | MeshObstacle) -> np.ndarray:
    """xy outline (n, 2) of an obstacle: a box's rectangle, a mesh's convex hull."""
    if isinstance(o, Box):
        (x0, y0, _), (x1, y1, _) = o.lo, o.hi
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    xy = np.asarray(o.vertices, dtype=float)[:, :2]
    try:
        return xy[ConvexHull(xy).vertices]
    except QhullError:  # a mesh seen edge-on from above (flat in xy): fall back to its bounds
        (x0, y0), (x1, y1) = xy.min(axis=0), xy.max(axis=0)
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])


def _same_geometry(a: Box | MeshObstacle, b: Box | MeshObstacle) -> bool:
    return type(a) is type(b) and np.allclose(a.lo, b.lo) and np.allclose(a.hi, b.hi)


def _frustum_polygons(frusta: Iterable[tuple[Any, Any, Any]]) -> list[np.ndarray]:
    from secure3d.geometry.frustum import frustum_corners

    polys = []
    for R, origin, frustum in frusta:
        xy = frustum_corners(R, origin, frustum)[:, :2]
        try:
            polys.append(xy[ConvexHull(xy).vertices])
        except QhullError:  # a camera looking straight up or down: no area from above
            continue
    return polys


def top_down_figure(
    bounds: Bounds,
    true_boxes: Sequence[Box],
    *,
    out_path: str | os.PathLike[str],
    **kwargs: Any,
) -> Path:
    """The paper-style top view of a run (:func:`draw_top_down`), saved atomically as an image.

    Parameters
    ----------
    bounds, true_boxes, **kwargs
        As for :func:`draw_top_down`.
    out_path : str or Path
        Image file to write; the format follows its suffix.

    Returns
    -------
    Path
        ``out_path``.
    """
    fig = Figure(figsize=(7.5, 7.5 * _aspect(bounds)))
    draw_top_down(fig.add_subplot(1, 1, 1), bounds, true_boxes, **kwargs)
    return save_figure(fig, out_path)


def top_down_panels(
    panels: Sequence[Mapping[str, Any]], *, out_path: str | os.PathLike[str]
) -> Path:
    """Paper-style top views side by side, left to right (the paper's (a) and (b) subfigures).

    Parameters
    ----------
    panels : one mapping per panel of :func:`draw_top_down`'s arguments, ``bounds`` and
        ``true_boxes`` included (panels may show different worlds).
    out_path : image file to write (atomically); the format follows its suffix.
    """
    if not panels:
        raise ConfigError("panels: need at least one panel")
    n = len(panels)
    fig = Figure(figsize=(9.0 * n, 7.5 * max(_aspect(p["bounds"]) for p in panels)))
    for i, panel in enumerate(panels):
        draw_top_down(fig.add_subplot(1, n, i + 1), **panel)
    fig.subplots_adjust(wspace=0.5)  # room for each panel's legend, drawn right of its axes
    return save_figure(fig, out_path)


def _draw_voxel_slices(
    ax: Axes,
    z: float,
    boxes: np.ndarray | None,
    colors: np.ndarray | None,
    claimed: np.ndarray | None,
    size: float | None,
) -> list[Any]:
    """Fill the true voxels and outline the claimed ones cut by the plane at height ``z``."""
    handles: list[Any] = []
    if boxes is not None and len(boxes):
        cut = (boxes[:, 0, 2] <= z) & (boxes[:, 1, 2] > z)
        lo, hi = boxes[cut, 0, :2], boxes[cut, 1, :2]
        if len(lo):
            polys = np.stack([lo, np.c_[hi[:, 0], lo[:, 1]], hi, np.c_[lo[:, 0], hi[:, 1]]], axis=1)
            face = KNOWN_COLOR if colors is None else np.asarray(colors)[cut] / 255.0
            ax.add_collection(
                PolyCollection(polys, facecolors=face, edgecolors="none", alpha=0.85, zorder=2)
            )
            handles.append(Patch(facecolor=KNOWN_COLOR, alpha=0.85, label="OctoMap voxels"))
    if claimed is not None and len(claimed) and size:
        cut = np.abs(claimed[:, 2] - z) < 0.5 * size
        c = claimed[cut, :2]
        if len(c):
            d = 0.5 * size
            polys = np.stack([c + [-d, -d], c + [d, -d], c + [d, d], c + [-d, d]], axis=1)
            ax.add_collection(
                PolyCollection(
                    polys, facecolors="none", edgecolors=PHANTOM_COLOR, linewidths=0.4, zorder=3
                )
            )
            handles.append(
                Patch(
                    facecolor="none", edgecolor=PHANTOM_COLOR, label="server map (claimed voxels)"
                )
            )
    return handles


def draw_top_down(
    ax: Axes,
    bounds: Bounds,
    true_boxes: Sequence[Box],
    *,
    hidden_names: Sequence[str] = (),
    claimed_boxes: Sequence[Box] | None = None,
    plans: Sequence[Any] = (),
    realised_paths: Mapping[str, np.ndarray] | None = None,
    detection_points: Mapping[str, np.ndarray] | Sequence[np.ndarray] | None = None,
    frusta: Sequence[tuple[Any, Any, Any]] = (),
    true_meshes: Sequence[MeshObstacle] = (),
    claimed_meshes: Sequence[MeshObstacle] = (),
    start: np.ndarray | None = None,
    goal: np.ndarray | None = None,
    collision_points: Sequence[np.ndarray] = (),
    ellipse_every: int = 1,
    z_slice: float | None = None,
    title: str | None = None,
    voxel_boxes: np.ndarray | None = None,
    voxel_colors: np.ndarray | None = None,
    claimed_voxels: np.ndarray | None = None,
    voxel_size: float | None = None,
) -> None:
    """Draw the paper-style top view of a run on ``ax``.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    bounds : Bounds
        World bounds; the axes show their xy extent.
    true_boxes, true_meshes : obstacles of the true world (filled; ``hidden_names`` black and
        hatched: the ones the server deleted).
    claimed_boxes, claimed_meshes : the server's claim. Claimed obstacles that are not in the
        truth with the same geometry (phantoms, shifted ones) are outlined dashed. ``None``: the
        server reports the truth minus the hidden obstacles.
    plans : sequence of plan-like objects
        With ``planner``, ``positions (K, 3)``, ``ellipsoid_centers (K, 3)``, ``ellipsoid_shapes
        (K, 3, 3)``: drawn dashed with their reactive ellipses (every ``ellipse_every``-th node).
    realised_paths : mapping label -> (T, 3) float
        Flown paths, drawn solid (colour by label: "secure" blue, "baseline" orange).
    detection_points : mapping label -> (3,) float, or sequence of (3,) float
        Where the hidden obstacle was first seen: red X.
    frusta : sequence of (R_world_from_optical (3, 3), origin (3,), PinholeFrustum)
        Camera fields of view, drawn as translucent wedges (the xy shadow of each pyramid).
    start, goal : (3,) float, optional
        Blue triangle and green circle, as in the paper.
    collision_points : sequence of (3,) float
        Where a realised path hit an obstacle: red star.
    z_slice : float, optional
        Height (m) of the horizontal section shown: only obstacles whose z-extent contains it are
        drawn, so floors and ceilings do not cover the map. Default: the start's height, else the
        median height of the plans and paths, else the middle of the bounds.
    voxel_boxes : (n, 2, 3) float, optional
        ``[lo, hi]`` of true OctoMap voxels (``world.octomap``): those cut by the slice are filled,
        in ``voxel_colors`` ((n, 3) uint8, a colour tree's) where given.
    claimed_voxels : (m, 3) float, optional
        Centres of the voxels (edge ``voxel_size``) the server's map claims occupied: those cut by
        the slice are outlined in red.
    """
    if not is_int_in(ellipse_every, 1):
        raise ConfigError(f"ellipse_every: must be a positive integer, got {ellipse_every!r}")
    hidden = set(hidden_names)
    z = _slice_height(z_slice, bounds, start, plans, realised_paths)
    truth, claimed, true_by_name = _sliced_obstacles(
        [*true_boxes, *true_meshes], claimed_boxes, claimed_meshes, hidden, z
    )
    # Layers in drawing order (their legend entries in the same order).
    handles: list[Any] = []
    handles += _draw_frusta(ax, frusta)
    handles += _draw_truth(
        ax, truth, hidden, z, voxel_boxes, voxel_colors, claimed_voxels, voxel_size
    )
    handles += _draw_claim_mismatch(ax, claimed, true_by_name)
    handles += _draw_plans(ax, plans, ellipse_every)
    handles += _draw_paths(ax, realised_paths)
    handles += _draw_markers(ax, detection_points, collision_points, start, goal)
    _frame(ax, bounds, title, handles)


def _sliced_obstacles(
    truth: list[Any],
    claimed_boxes: Sequence[Box] | None,
    claimed_meshes: Sequence[MeshObstacle],
    hidden: set[str],
    z: float,
) -> tuple[list[Any], list[Any], dict[str, Any]]:
    """The true and the claimed obstacles cut by the slice at height ``z`` (the claim defaults to
    the truth minus the ``hidden`` ones), and every true obstacle by name."""
    if claimed_boxes is None and not claimed_meshes:
        claimed = [o for o in truth if o.name not in hidden]
    else:
        claimed = [*(claimed_boxes or ()), *claimed_meshes]
    true_by_name = {o.name: o for o in truth}
    truth = [o for o in truth if o.lo[2] <= z <= o.hi[2]]
    claimed = [o for o in claimed if o.lo[2] <= z <= o.hi[2]]
    return truth, claimed, true_by_name


def _draw_frusta(ax: Axes, frusta: Sequence[tuple[Any, Any, Any]]) -> list[Any]:
    """Camera fields of view as translucent wedges (the xy shadow of each pyramid)."""
    if not frusta:
        return []
    polys = _frustum_polygons(frusta)
    ax.add_collection(
        PolyCollection(polys, facecolors=FRUSTUM_COLOR, edgecolors="none", alpha=0.12, zorder=1)
    )
    return [Patch(facecolor=FRUSTUM_COLOR, alpha=0.3, label="camera field of view")]


def _draw_truth(
    ax: Axes,
    truth: Sequence[Box | MeshObstacle],
    hidden: set[str],
    z: float,
    voxel_boxes: np.ndarray | None,
    voxel_colors: np.ndarray | None,
    claimed_voxels: np.ndarray | None,
    voxel_size: float | None,
) -> list[Any]:
    """True obstacles cut by the slice (hidden ones black and hatched) and the voxel slices."""
    handles: list[Any] = []
    for o in truth:
        is_hidden = o.name in hidden
        ax.add_patch(
            Polygon(
                _footprint(o),
                closed=True,
                facecolor=HIDDEN_COLOR if is_hidden else KNOWN_COLOR,
                # Hatch lines take the edge colour: grey keeps them visible on black.
                edgecolor="0.6" if is_hidden else "black",
                hatch="////" if is_hidden else None,
                alpha=0.9 if is_hidden else 0.75,
                zorder=3,
            )
        )
    handles += _draw_voxel_slices(ax, z, voxel_boxes, voxel_colors, claimed_voxels, voxel_size)
    if any(o.name not in hidden for o in truth):
        handles.append(Patch(facecolor=KNOWN_COLOR, alpha=0.75, label="known obstacle"))
    if any(o.name in hidden for o in truth):
        handles.append(Patch(facecolor=HIDDEN_COLOR, hatch="////", label="hidden obstacle"))
    return handles


def _draw_claim_mismatch(
    ax: Axes, claimed: Sequence[Box | MeshObstacle], true_by_name: Mapping[str, Any]
) -> list[Any]:
    """Claimed obstacles not in the truth (phantoms) or moved from it, outlined dashed."""
    handles: list[Any] = []
    fake = [o for o in claimed if o.name not in true_by_name]
    moved = [
        o for o in claimed if o.name in true_by_name and not _same_geometry(o, true_by_name[o.name])
    ]
    for group, color, label in (
        (fake, PHANTOM_COLOR, "phantom (claimed)"),
        (moved, KNOWN_COLOR, "claimed position (moved)"),
    ):
        for o in group:
            ax.add_patch(
                Polygon(
                    _footprint(o),
                    closed=True,
                    fill=False,
                    edgecolor=color,
                    linestyle="--",
                    linewidth=1.5,
                    zorder=3,
                )
            )
        if group:
            handles.append(Line2D([], [], color=color, linestyle="--", label=label))
    return handles


def _draw_plans(ax: Axes, plans: Sequence[Any], ellipse_every: int) -> list[Any]:
    """Planned paths dashed, with the xy shadows of their reactive sets."""
    handles: list[Any] = []
    for i, plan in enumerate(plans):
        label = str(getattr(plan, "planner", f"plan {i}"))
        color = color_for(label, i)
        pos = np.asarray(plan.positions, dtype=float).reshape(-1, 3)
        ax.plot(pos[:, 0], pos[:, 1], "--", color=color, linewidth=1.6, zorder=5)
        handles.append(Line2D([], [], color=color, linestyle="--", label=f"{label} plan"))
        centres = np.asarray(plan.ellipsoid_centers, dtype=float).reshape(-1, 3)[::ellipse_every]
        if len(centres):
            shapes = np.asarray(plan.ellipsoid_shapes, dtype=float)[::ellipse_every]
            w, h, ang = ellipse_shadows(shapes)
            ax.add_collection(
                EllipseCollection(
                    w,
                    h,
                    ang,
                    units="xy",
                    offsets=centres[:, :2],
                    offset_transform=ax.transData,
                    facecolors=color,
                    edgecolors=color,
                    alpha=0.15,
                    linewidths=0.8,
                    zorder=4,
                )
            )
            handles.append(Patch(facecolor=color, alpha=0.3, label=f"{label} reactive sets"))
    return handles


def _draw_paths(ax: Axes, realised_paths: Mapping[str, np.ndarray] | None) -> list[Any]:
    """Flown paths, solid."""
    handles: list[Any] = []
    for i, (label, path) in enumerate((realised_paths or {}).items()):
        p = np.asarray(path, dtype=float).reshape(-1, 3)
        color = color_for(label, i)
        ax.plot(p[:, 0], p[:, 1], "-", color=color, linewidth=2.2, zorder=6)
        handles.append(Line2D([], [], color=color, linewidth=2.2, label=f"{label} realised"))
    return handles


def _marker(
    ax: Axes,
    xs: Any,
    ys: Any,
    marker: str,
    color: str,
    sizes: tuple[float, float],
    zorder: float,
    label: str,
    **style: Any,
) -> Line2D:
    """Plot markers at (xs, ys) (``sizes``: on the map, in the legend); return the legend entry."""
    ax.plot(xs, ys, marker, color=color, markersize=sizes[0], zorder=zorder, **style)
    return Line2D(
        [],
        [],
        color=color,
        marker=marker,
        linestyle="none",
        markersize=sizes[1],
        label=label,
        **style,
    )


def _draw_markers(
    ax: Axes,
    detection_points: Mapping[str, np.ndarray] | Sequence[np.ndarray] | None,
    collision_points: Sequence[np.ndarray],
    start: np.ndarray | None,
    goal: np.ndarray | None,
) -> list[Any]:
    """Detection points (red X), collisions (red star), start (blue triangle) and goal (green
    circle), as in the paper's figures."""
    handles: list[Any] = []
    det = _points(detection_points)
    if len(det):
        handles.append(
            _marker(
                ax,
                det[:, 0],
                det[:, 1],
                "x",
                "red",
                (13, 10),
                8,
                "detection point",
                markeredgewidth=3,
            )
        )
    hits = _points(collision_points)
    if len(hits):
        handles.append(
            _marker(
                ax,
                hits[:, 0],
                hits[:, 1],
                "*",
                "red",
                (18, 12),
                9,
                "collision",
                markeredgecolor="black",
            )
        )
    for point, marker, color, label in (
        (start, "^", "tab:blue", "start"),
        (goal, "o", "tab:green", "goal"),
    ):
        if point is not None:
            q = np.asarray(point, dtype=float)
            handles.append(
                _marker(ax, q[0], q[1], marker, color, (12, 10), 9, label, markeredgecolor="black")
            )
    return handles


def _frame(ax: Axes, bounds: Bounds, title: str | None, handles: list[Any]) -> None:
    """The bounds' outline, limits with a 2 % margin, equal aspect, labels, grid and legend."""
    ax.add_patch(
        Rectangle(
            bounds.lo[:2],
            bounds.hi[0] - bounds.lo[0],
            bounds.hi[1] - bounds.lo[1],
            fill=False,
            edgecolor="0.4",
            linewidth=1.0,
            zorder=2,
        )
    )
    margin = 0.02 * max(bounds.hi[0] - bounds.lo[0], bounds.hi[1] - bounds.lo[1])
    ax.set_xlim(bounds.lo[0] - margin, bounds.hi[0] + margin)
    ax.set_ylim(bounds.lo[1] - margin, bounds.hi[1] + margin)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, linewidth=0.4, alpha=0.5)
    if title:
        ax.set_title(title)
    if handles:
        ax.legend(
            handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False
        )


def _points(points: Mapping[str, np.ndarray] | Sequence[np.ndarray] | None) -> np.ndarray:
    if points is None:
        return np.zeros((0, 3))
    values = list(points.values()) if isinstance(points, Mapping) else list(points)
    if not values:
        return np.zeros((0, 3))
    return np.asarray(values, dtype=float).reshape(-1, 3)


def _slice_height(
    z_slice: float | None,
    bounds: Bounds,
    start: np.ndarray | None,
    plans: Sequence[Any],
    paths: Mapping[str, np.ndarray] | None,
) -> float:
    if z_slice is not None:
        z = float(z_slice)
        if not np.isfinite(z):
            raise ConfigError(f"z_slice: must be finite, got {z_slice!r}")
        return z
    if start is not None:
        return float(np.asarray(start, dtype=float).reshape(3)[2])
    heights = [np.asarray(p.positions, dtype=float).reshape(-1, 3)[:, 2] for p in plans]
    heights += [np.asarray(p, dtype=float).reshape(-1, 3)[:, 2] for p in (paths or {}).values()]
    if heights and sum(len(h) for h in heights):
        return float(np.median(np.concatenate(heights)))
    return 0.5 * (bounds.lo[2] + bounds.hi[2])


def _aspect(bounds: Bounds) -> float:
    """Height/width of the plot area, clipped so a long corridor still gets a readable figure."""
    ext = np.subtract(bounds.hi, bounds.lo)
    return float(np.clip(ext[1] / ext[0], 0.35, 1.6))
