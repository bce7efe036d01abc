"""World -> meshes: geometry and labels of the union mesh."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from secure3d.errors import GeometryError
from secure3d.simulation.scene import (
    VOXEL_NAME,
    box_arrays,
    check_voxel_boxes,
    merged_voxel_boxes,
    obstacle_meshes,
    voxel_boxes_from_centres,
    world_trimesh,
)
from secure3d.world.spec import Box, MeshObstacle


def _tetra(name: str, offset) -> MeshObstacle:
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=float) + offset
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return MeshObstacle(name, v, f)


def test_box_arrays_are_closed_boxes_with_the_right_volume(rng):
    lo = rng.uniform(-5, 5, (6, 3))
    hi = lo + rng.uniform(0.1, 2, (6, 3))
    v, f = box_arrays(lo, hi)
    assert v.shape == (48, 3) and f.shape == (72, 3)
    for k in range(6):
        m = trimesh.Trimesh(v, f[12 * k : 12 * k + 12], process=True)
        assert m.is_watertight and m.is_winding_consistent
        np.testing.assert_allclose(m.volume, np.prod(hi[k] - lo[k]), rtol=1e-12, err_msg=f"box {k}")
        np.testing.assert_allclose(m.bounds, [lo[k], hi[k]], atol=1e-12)


def test_world_trimesh_labels_every_face_with_its_obstacle():
    boxes = [Box("a", (0, 0, 0), (1, 1, 1)), Box("b", (3, 0, 0), (4, 2, 1))]
    meshes = [_tetra("t", (10, 0, 0))]
    voxels = voxel_boxes_from_centres(np.array([[20.0, 0, 0], [20.1, 0, 0]]), 0.1)
    mesh = world_trimesh(boxes, meshes, voxels)
    names = mesh.metadata["obstacle_names"]
    assert names == ("a", "b", "t", VOXEL_NAME)
    labels = mesh.face_attributes["obstacle"]
    assert labels.shape == (len(mesh.faces),)
    # Independent check: each labelled face's centroid lies inside that obstacle's bounds.
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    bounds = {
        "a": ([0, 0, 0], [1, 1, 1]),
        "b": ([3, 0, 0], [4, 2, 1]),
        "t": ([10, 0, 0], [11, 1, 1]),
        VOXEL_NAME: ([19.95, -0.05, -0.05], [20.15, 0.05, 0.05]),
    }
    for i, name in enumerate(names):
        lo, hi = (np.array(b) for b in bounds[name])
        c = centroids[labels == i]
        assert len(c) > 0, name
        assert np.all((c >= lo - 1e-9) & (c <= hi + 1e-9)), name
    assert np.bincount(labels).tolist() == [12, 12, 4, 24]


def test_obstacle_meshes_pairs_and_empty_world():
    parts = obstacle_meshes([Box("a", (0, 0, 0), (1, 2, 3))])
    assert [n for n, _ in parts] == ["a"]
    np.testing.assert_allclose(parts[0][1].volume, 6.0, rtol=1e-12)
    empty = world_trimesh()
    assert len(empty.faces) == 0 and empty.metadata["obstacle_names"] == ()


def test_check_voxel_boxes_rejects_bad_input():
    with pytest.raises(GeometryError, match="shape"):
        check_voxel_boxes(np.zeros((3, 3)))
    with pytest.raises(GeometryError, match="hi must exceed lo"):
        check_voxel_boxes(np.array([[[0, 0, 0], [1, 1, 1]], [[0, 0, 0], [1, 0, 1]]]))
    with pytest.raises(GeometryError, match="NaN"):
        check_voxel_boxes(np.array([[[0, 0, np.nan], [1, 1, 1]]]))
    assert check_voxel_boxes([]).shape == (0, 2, 3)


def test_voxel_results_are_reused_by_content_and_never_shared(rng):
    """The second call with voxel boxes of the same bytes reuses the first's merge and surface:
    the same answers as a fresh build, copies the caller may change, and a change of the caller's
    array after a call is a new content (a new build)."""
    from secure3d.simulation import scene

    cells = np.unique(rng.integers(0, 12, size=(300, 3)), axis=0)
    vb = voxel_boxes_from_centres((cells + 0.5) * 0.1, 0.1)
    merged = merged_voxel_boxes(vb)
    np.testing.assert_array_equal(merged, scene._merged_voxel_boxes(vb.copy()))
    merged[:] = 0.0  # the caller's copy
    np.testing.assert_array_equal(merged_voxel_boxes(vb), scene._merged_voxel_boxes(vb.copy()))
    ((_, first),) = obstacle_meshes(voxel_boxes=vb)
    first.vertices[:] = 0.0
    ((_, second),) = obstacle_meshes(voxel_boxes=vb)
    v, f = scene._voxel_surface(vb.copy())
    np.testing.assert_array_equal(second.vertices, v)
    np.testing.assert_array_equal(second.faces, f)
    vb[0] += 5.0  # the same array, other content: not served from the cache
    ((_, moved),) = obstacle_meshes(voxel_boxes=vb)
    assert moved.vertices.max() > v.max() + 4.0
    np.testing.assert_array_equal(merged_voxel_boxes(vb), scene._merged_voxel_boxes(vb.copy()))


def test_voxel_cache_keeps_to_its_byte_budget(rng, monkeypatch):
    """Least recently used entries go once the cache holds more than its bytes; a value larger
    than the whole budget is built and returned but not kept."""
    from secure3d._bounded_cache import BoundedCache
    from secure3d.simulation import scene

    monkeypatch.setattr(
        scene, "_CONTENT", BoundedCache(scene.CONTENT_CACHE_SIZE, 3 * 8 * 100, scene._nbytes)
    )
    built = []

    def build(vb):  # 800 bytes a value: three fit at most
        built.append(1)
        return np.zeros(100)

    boxes = [voxel_boxes_from_centres(rng.uniform(0, 1, (5, 3)), 0.1) for _ in range(4)]
    for vb in boxes:
        scene.by_voxel_content("test", vb, build)
    assert len(scene._CONTENT) == 3 and len(built) == 4
    scene.by_voxel_content("test", boxes[3], build)  # kept
    scene.by_voxel_content("test", boxes[0], build)  # evicted first: built again
    assert len(built) == 5
    scene.by_voxel_content("test", boxes[1], lambda vb: np.zeros(1000))  # over budget
    assert len(scene._CONTENT) == 3
    assert scene._CONTENT.held <= scene._CONTENT.budget


def test_voxel_cache_refuses_what_is_not_voxel_boxes():
    from secure3d.simulation import scene

    with pytest.raises(GeometryError, match="voxel_boxes"):
        scene.by_voxel_content("merged", np.zeros((3, 3)), scene._merged_voxel_boxes)
    with pytest.raises(GeometryError, match="build callable"):
        scene.by_voxel_content("merged", np.zeros((0, 2, 3)), None)
