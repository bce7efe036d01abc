"""A world.octomap's voxels, in a colour tree's colours, in the Rerun recording and the PNG."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
import octomap  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from secure3d.viz.figures import draw_top_down  # noqa: E402
from secure3d.viz.rerun_log import RerunRecorder  # noqa: E402
from secure3d.world.attacks import octomap_voxel_boxes, octomap_voxel_colors  # noqa: E402
from secure3d.world.spec import Bounds  # noqa: E402

from .test_rerun_log import read_rows  # noqa: E402


def colour_tree(tmp_path: Path) -> Path:
    """A ColorOcTree .ot: a red wall at x in [1, 1.2) and a blue one at x in [2, 2.2)."""
    tree = octomap.ColorOcTree(0.1)
    ys, zs = np.meshgrid(np.arange(0.05, 1.0, 0.1), np.arange(0.05, 1.0, 0.1))
    for x, rgb in ((1.05, (255, 0, 0)), (2.05, (0, 0, 255))):
        for dx in (0.0, 0.1):
            pts = np.c_[np.full(ys.size, x + dx), ys.ravel(), zs.ravel()]
            for p in pts:
                tree.updateNode(p, True)
                tree.setNodeColor(p, *rgb)
    path = tmp_path / "walls.ot"
    assert tree.write(str(path).encode())
    return path


def test_colour_octomap_voxels_in_rerun(tmp_path: Path) -> None:
    path = colour_tree(tmp_path)
    boxes, colors = octomap_voxel_boxes(path), octomap_voxel_colors(path)
    assert colors is not None and len(colors) == len(boxes) > 0
    out = tmp_path / "run.rrd"
    with RerunRecorder(out) as rec:
        rec.log_world(true_voxels=boxes, true_voxel_colors=colors)
    rows = read_rows(out)["/world/truth/voxels"][0]
    logged = np.array(rows["Boxes3D:colors"], dtype=np.uint64)
    rgb = np.stack([(logged >> 24) & 255, (logged >> 16) & 255, (logged >> 8) & 255], 1)
    red = boxes[:, 0, 0] < 1.5
    np.testing.assert_array_equal(rgb[red], np.tile([255, 0, 0], (red.sum(), 1)))
    np.testing.assert_array_equal(rgb[~red], np.tile([0, 0, 255], ((~red).sum(), 1)))


def test_colour_octomap_slice_in_the_png(tmp_path: Path) -> None:
    path = colour_tree(tmp_path)
    boxes, colors = octomap_voxel_boxes(path), octomap_voxel_colors(path)
    fig = Figure()
    ax = fig.add_subplot(1, 1, 1)
    claimed = np.array([[0.55, 0.55, 0.45], [0.55, 0.55, 5.0]])
    draw_top_down(
        ax,
        Bounds((0, 0, 0), (3, 1, 1)),
        [],
        voxel_boxes=boxes,
        voxel_colors=colors,
        claimed_voxels=claimed,
        voxel_size=0.1,
        z_slice=0.45,
    )
    cols = [c for c in ax.collections if isinstance(c, PolyCollection)]
    filled = [c for c in cols if len(c.get_facecolors()) and c.get_facecolors()[0][3] > 0]
    faces = filled[0].get_facecolors()[:, :3]
    # one slice through both walls (0.2 m thick, 1 m long each; OctoMap pruned equal siblings
    # into bigger leaves), in their colours
    area = sum(np.ptp(p.vertices[:, 0]) * np.ptp(p.vertices[:, 1]) for p in filled[0].get_paths())
    assert np.isclose(area, 0.4)
    assert {tuple(np.round(f, 3)) for f in faces} == {(1.0, 0.0, 0.0), (0.0, 0.0, 1.0)}
    outlined = [c for c in cols if c not in filled]
    assert len(outlined) == 1 and len(outlined[0].get_paths()) == 1  # only the claim at z 0.45
