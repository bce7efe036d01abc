"""Voxel boundary meshes: closed, outward oriented, exact volume and area."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest
import trimesh

from secure3d.errors import ConfigError, GeometryError
from secure3d.mapping import OccupancyMap, surface
from secure3d.mapping.surface import boundary_mesh, surface_mask


def exposed_faces(cells: np.ndarray) -> int:
    """Count faces between a cell of the set and one outside it (reference, set lookups)."""
    s = {tuple(c) for c in cells.tolist()}
    steps = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    return sum((c[0] + d[0], c[1] + d[1], c[2] + d[2]) not in s for c in s for d in steps)


def signed_volume(v: np.ndarray, f: np.ndarray) -> float:
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


@pytest.mark.parametrize("density", [0.1, 0.5, 0.95])
def test_random_sets_give_closed_oriented_surfaces(rng, density):
    grid = np.stack(np.meshgrid(*[np.arange(12)] * 3, indexing="ij"), -1).reshape(-1, 3)
    cells = grid[rng.random(grid.shape[0]) < density] + 32760
    v, f = boundary_mesh(cells)
    assert f.shape[0] == 2 * exposed_faces(cells)
    # Closed and consistently oriented: each directed edge is used as often as its reverse
    # (twice where two voxels touch along an edge only, once elsewhere).
    edges = Counter(map(tuple, np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]).tolist()))
    assert all(edges[(b, a)] == n for (a, b), n in edges.items())
    assert set(edges.values()) <= {1, 2}
    # Divergence theorem: outward orientation gives exactly the voxel volume.
    assert signed_volume(v.astype(float), f) == pytest.approx(cells.shape[0], abs=1e-6)
    assert np.unique(v, axis=0).shape[0] == v.shape[0], "corners are shared, not duplicated"


def test_solid_without_edge_contacts_is_a_watertight_volume():
    a = np.stack(np.meshgrid(np.arange(4), np.arange(3), np.arange(2), indexing="ij"), -1)
    b = np.stack(np.meshgrid(np.arange(3, 6), np.arange(2, 5), np.arange(1, 3), indexing="ij"), -1)
    cells = np.unique(np.concatenate([a.reshape(-1, 3), b.reshape(-1, 3)]), axis=0)
    v, f = boundary_mesh(cells)
    mesh = trimesh.Trimesh(v.astype(float), f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.is_volume
    assert mesh.volume == pytest.approx(cells.shape[0])
    assert mesh.area == pytest.approx(exposed_faces(cells))


def test_map_surface_mesh_in_metres(rng):
    m = OccupancyMap(0.1)
    m.set_claim_boxes([[0.01, 0.01, 0.01]], [[0.49, 0.29, 0.19]])
    v, f = m.surface_mesh("claimed")
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_volume
    assert mesh.volume == pytest.approx(0.5 * 0.3 * 0.2, rel=1e-9)
    np.testing.assert_allclose(mesh.bounds, [[0, 0, 0], [0.5, 0.3, 0.2]], atol=1e-12)
    m.insert_point_cloud(rng.uniform(-1, 1, (300, 3)), np.zeros(3))
    v_known, f_known = m.surface_mesh("known")
    v_sensed, f_sensed = m.surface_mesh("sensed")
    assert f_known.shape[0] > f_sensed.shape[0] > 0
    with pytest.raises(ConfigError, match="which"):
        m.surface_mesh("free")


def test_surface_mask_keeps_the_cells_with_a_face_outside(rng, monkeypatch):
    steps = [(1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)]
    for _ in range(20):
        cells = np.argwhere(rng.random((8, 9, 7)) < rng.uniform(0.3, 0.95))
        cells = cells + rng.integers(-1000, 1000, 3)
        s = {tuple(c) for c in cells.tolist()}
        want = [any((c[0] + d[0], c[1] + d[1], c[2] + d[2]) not in s for d in steps) for c in s]
        got = surface_mask(np.array(sorted(s)))
        np.testing.assert_array_equal(got, [w for _, w in sorted(zip(s, want, strict=True))])
    # a solid 5^3 block: its 98 outer cells; no cells, no surface
    block = np.argwhere(np.ones((5, 5, 5), bool))
    assert surface_mask(block).sum() == 5**3 - 3**3
    assert surface_mask(np.zeros((0, 3), int)).shape == (0,)
    # beyond the grid budget every cell counts as surface (drawn, never wrongly hidden)
    monkeypatch.setattr(surface, "MAX_SURFACE_GRID", 100)
    assert surface_mask(block).all()
    for bad in (np.zeros((4, 2), int), np.zeros(3, int), block + 0.5):
        with pytest.raises(GeometryError, match="cells"):
            surface_mask(bad)
