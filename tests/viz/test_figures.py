"""Figures: the ellipse shadows are exact, the top view draws what it says, files are atomic."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from matplotlib.collections import EllipseCollection, PolyCollection
from matplotlib.figure import Figure
from matplotlib.patches import Polygon

from secure3d.errors import ConfigError, GeometryError
from secure3d.geometry.frustum import PinholeFrustum
from secure3d.viz.figures import (
    draw_top_down,
    ellipse_shadows,
    save_figure,
    top_down_figure,
    top_down_panels,
)
from secure3d.viz.speed_figure import speed_profile_figure
from secure3d.world.spec import Bounds, Box

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
R_LOOK_X = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


@dataclass(frozen=True)
class StandInPlan:
    planner: str
    positions: np.ndarray
    ellipsoid_centers: np.ndarray
    ellipsoid_shapes: np.ndarray


def straight_plan(planner: str, y: float, K: int = 10) -> StandInPlan:
    t = np.linspace(0, 1, K)
    pos = np.column_stack([1 + 6 * t**2, np.full(K, y), np.full(K, 1.0)])
    shapes = np.stack([np.diag([0.2 + 0.3 * s, 0.2, 0.2]) for s in t])
    return StandInPlan(planner, pos, pos + [0.2, 0, 0], shapes)


BOUNDS = Bounds((0, 0, 0), (8, 4, 3))
BOXES = [
    Box("floor", (0, 0, -0.1), (8, 4, 0.0)),
    Box("wall", (3, 2.5, 0), (4, 4, 3)),
    Box("crate", (5, 1.5, 0), (5.5, 2.0, 3)),
]
CLAIMED = [Box("wall", (3, 2.5, 0), (4, 4, 3)), Box("ghost_box", (6, 3, 0), (7, 3.5, 3))]


def test_ellipse_shadow_support_matches_the_3d_ellipsoid(rng):
    A = rng.normal(size=(40, 3, 3))
    M = A @ np.swapaxes(A, 1, 2) + 0.05 * np.eye(3)
    w, h, ang = ellipse_shadows(M)
    assert np.all(w >= h)
    theta = np.radians(ang)
    u = np.stack([np.cos(theta), np.sin(theta)], axis=-1)
    v = np.stack([-np.sin(theta), np.cos(theta)], axis=-1)
    for n2 in rng.normal(size=(20, 2)):
        n2 = n2 / np.linalg.norm(n2)
        # Support of E = {c + M z} in direction (n, 0) is |M (n, 0)| (independent formula).
        exact = np.linalg.norm(M @ np.array([n2[0], n2[1], 0.0]), axis=-1)
        ellipse = np.sqrt((w / 2 * (u @ n2)) ** 2 + (h / 2 * (v @ n2)) ** 2)
        np.testing.assert_allclose(ellipse, exact, rtol=1e-10, err_msg="shadow support")


def test_top_down_draws_the_section_obstacles_plans_and_markers():
    fig = Figure()
    ax = fig.add_subplot(1, 1, 1)
    frustum = PinholeFrustum(np.radians(90), np.radians(70), 3.0)
    draw_top_down(
        ax,
        BOUNDS,
        BOXES,
        hidden_names=["crate"],
        claimed_boxes=CLAIMED,
        plans=[straight_plan("secure", 1.0), straight_plan("baseline", 2.0)],
        realised_paths={"secure": straight_plan("secure", 1.0).positions[:6]},
        detection_points={"secure": np.array([4.0, 1.0, 1.0])},
        frusta=[(R_LOOK_X, np.array([1.0, 1.0, 1.0]), frustum)],
        start=np.array([1.0, 1.0, 1.0]),
        goal=np.array([7.0, 1.0, 1.0]),
        ellipse_every=2,
    )
    polys = [p for p in ax.patches if isinstance(p, Polygon)]
    filled = [p for p in polys if p.get_fill()]
    # The floor is below the slice at z = 1 and is not drawn; wall and crate are.
    assert len(filled) == 2
    assert sum(p.get_hatch() == "////" for p in filled) == 1
    outlines = [p for p in polys if not p.get_fill()]
    assert len(outlines) == 1 and outlines[0].get_linestyle() == "--"
    np.testing.assert_allclose(outlines[0].get_xy()[:4], [[6, 3], [7, 3], [7, 3.5], [6, 3.5]])
    ellipses = [c for c in ax.collections if isinstance(c, EllipseCollection)]
    assert [len(c.get_offsets()) for c in ellipses] == [5, 5]
    wedges = [
        c
        for c in ax.collections
        if isinstance(c, PolyCollection) and not isinstance(c, EllipseCollection)
    ]
    assert len(wedges) == 1
    wedge = wedges[0].get_paths()[0].vertices
    # Looking along +x from (1, 1) with a 90 deg fov and far plane 3: apex and far corners.
    for corner in ([1, 1], [4, -2], [4, 4]):
        assert np.min(np.linalg.norm(wedge - corner, axis=1)) < 1e-9, corner
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    for expected in (
        "known obstacle",
        "hidden obstacle",
        "phantom (claimed)",
        "secure plan",
        "baseline plan",
        "secure realised",
        "detection point",
        "start",
        "goal",
        "camera field of view",
    ):
        assert expected in labels
    lines = {line.get_label(): line for line in ax.lines}
    dashed = [ln for ln in ax.lines if ln.get_linestyle() == "--"]
    assert len(dashed) == 2 and len(lines) >= 4


def test_top_down_and_speed_files_are_pngs_written_atomically(tmp_path):
    out = top_down_figure(
        BOUNDS,
        BOXES,
        out_path=tmp_path / "top.png",
        hidden_names=["crate"],
        plans=[straight_plan("secure", 1.0)],
        title="test",
    )
    assert out.read_bytes()[:8] == PNG_MAGIC
    t = np.linspace(0, 3, 50)
    speed = speed_profile_figure(
        {"secure": (t, np.sin(t) ** 2), "baseline": (t[:30], 2 * np.sin(t[:30]) ** 2)},
        tmp_path / "speed.png",
        markers={"secure": [(1.5, "obstacle seen")]},
        speed_limit=2.5,
    )
    assert speed.read_bytes()[:8] == PNG_MAGIC
    assert sorted(p.name for p in tmp_path.iterdir()) == ["speed.png", "top.png"]


def test_panels_draw_each_world_side_by_side(tmp_path):
    narrow = [Box("crate", (2.0, 2.0, 0.0), (2.5, 2.5, 2.0))]
    panels = [
        {"bounds": BOUNDS, "true_boxes": BOXES, "plans": [straight_plan("secure", 1.0)]},
        {"bounds": BOUNDS, "true_boxes": narrow, "title": "(b)"},
    ]
    out = top_down_panels(panels, out_path=tmp_path / "panels.png")
    assert out.read_bytes()[:8] == PNG_MAGIC
    assert [p.name for p in tmp_path.iterdir()] == ["panels.png"]
    with pytest.raises(ConfigError, match="at least one panel"):
        top_down_panels([], out_path=tmp_path / "none.png")


def test_failed_save_leaves_the_old_file_and_no_temporary(tmp_path):
    out = tmp_path / "fig.png"
    out.write_bytes(b"old")

    class Exploding(Figure):
        def savefig(self, *args, **kwargs):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        save_figure(Exploding(), out)
    assert out.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["fig.png"]


def test_bad_input_is_rejected(tmp_path):
    with pytest.raises(ConfigError, match="folder"):
        save_figure(Figure(), tmp_path / "missing" / "x.png")
    with pytest.raises(ConfigError, match="series"):
        speed_profile_figure({}, tmp_path / "x.png")
    with pytest.raises(GeometryError, match="baseline"):
        speed_profile_figure({"baseline": (np.arange(3), np.arange(4))}, tmp_path / "x.png")
    with pytest.raises(ConfigError, match="ellipse_every"):
        draw_top_down(Figure().add_subplot(), BOUNDS, BOXES, ellipse_every=0)
