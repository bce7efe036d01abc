"""The true world as triangle meshes, for the simulator's camera and figures.

Boxes, mesh obstacles and (optionally) occupied voxels of an OctoMap become one labelled
:class:`trimesh.Trimesh`: ``mesh.face_attributes["obstacle"][i]`` is the index into
``mesh.metadata["obstacle_names"]`` of the obstacle that face ``i`` belongs to. The depth camera
uses the label of the triangle a ray hits to tell which obstacle it saw (DESIGN.md section 2: only
the simulator sees the truth).

Voxel boxes are passed as one ``(n, 2, 3)`` array of ``[lo, hi]`` corners and share the single name
:data:`VOXEL_NAME`: an OctoMap has no per-voxel identity worth reporting.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence

import numpy as np
import trimesh

from secure3d._bounded_cache import BoundedCache
from secure3d.errors import GeometryError
from secure3d.geometry.box_mesh import UNIT_BOX as _UNIT_BOX
from secure3d.geometry.box_mesh import box_arrays
from secure3d.world.spec import Box, MeshObstacle

#: Name under which all voxel boxes of a world are reported.
VOXEL_NAME = "voxels"


def check_voxel_boxes(voxel_boxes: object) -> np.ndarray:
    """Return ``voxel_boxes`` as a ``(n, 2, 3)`` float array of ``[lo, hi]`` corners.

    Raises
    ------
    GeometryError
        Wrong shape, non-finite values or a box with ``hi <= lo`` on some axis.
    """
    arr = np.asarray(voxel_boxes, dtype=float)
    if arr.size == 0:
        return np.zeros((0, 2, 3))
    if arr.ndim != 3 or arr.shape[1:] != (2, 3):
        raise GeometryError(f"voxel_boxes: expected shape (n, 2, 3) of [lo, hi], got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise GeometryError("voxel_boxes: contains NaN or inf")
    bad = np.flatnonzero(np.any(arr[:, 1] <= arr[:, 0], axis=1))
    if bad.size:
        k = int(bad[0])
        raise GeometryError(
            f"voxel_boxes: hi must exceed lo on every axis; box {k} is {arr[k].tolist()}"
        )
    return arr


def voxel_boxes_from_centres(centres: np.ndarray, size: float) -> np.ndarray:
    """Cubes of edge ``size`` (m) around ``centres`` (n, 3) float, as ``(n, 2, 3)`` [lo, hi]."""
    c = np.asarray(centres, dtype=float).reshape(-1, 3)
    if not size > 0:
        raise GeometryError(f"voxel size must be > 0, got {size!r}")
    half = 0.5 * float(size)
    return np.stack([c - half, c + half], axis=1)


#: Which side of the box each unit-box triangle lies on: axis (0, 1, 2) and sign (0: -, 1: +).
_TRIANGLE_SIDE = np.argmax(np.abs(_UNIT_BOX.face_normals), axis=1) * 2 + (
    np.max(_UNIT_BOX.face_normals, axis=1) > 0.5
)


def _grid_cells(ilo: np.ndarray, ihi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every grid cell (m, 3) int64 of the integer boxes [ilo, ihi), and the box of each (m,)."""
    ext = ihi - ilo
    cells, owner = [np.zeros((0, 3), np.int64)], [np.zeros(0, np.int64)]
    k = int(ext.max()) + 1 if len(ext) else 1
    size_key = (ext[:, 0] * k + ext[:, 1]) * k + ext[:, 2]
    sizes, first, which = np.unique(size_key, return_index=True, return_inverse=True)
    for g in range(len(sizes)):  # one batch per box size (octomap: 1, 2, 4, ... cells)
        shape = ext[first[g]]
        rows = np.flatnonzero(which == g)
        offs = np.stack(np.meshgrid(*(np.arange(k) for k in shape), indexing="ij"), -1)
        cells.append((ilo[rows, None, :] + offs.reshape(1, -1, 3)).reshape(-1, 3))
        owner.append(np.repeat(rows, offs.size // 3))
    return np.concatenate(cells), np.concatenate(owner)


#: Largest grid (cells) held as a dense boolean array; larger ones are looked up in sorted keys.
_DENSE_CELLS = 1 << 26


def _occupancy(cells: np.ndarray, span: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """Membership test for the grid cells ``cells`` (m, 3), all in ``[0, span)``: a function
    from cells (k, 3) in that range to (k,) bool."""
    if int(np.prod(span)) <= _DENSE_CELLS:
        grid = np.zeros(tuple(int(v) for v in span), bool)
        grid[tuple(cells.T)] = True
        return lambda c: grid[tuple(c.T)]

    def key(c: np.ndarray) -> np.ndarray:
        return (c[:, 0] * span[1] + c[:, 1]) * span[2] + c[:, 2]

    occupied = np.unique(key(cells))
    return lambda c: (
        occupied[np.minimum(np.searchsorted(occupied, key(c)), len(occupied) - 1)] == key(c)
    )


def _on_one_grid(lo: np.ndarray, hi: np.ndarray) -> tuple[float, np.ndarray, np.ndarray] | None:
    """(pitch, ilo, ihi) of boxes ``lo``, ``hi`` (n >= 1, 3) whose corners are multiples of their
    smallest edge (the pitch), as OctoMap leaves are: the integer boxes [ilo, ihi) (n, 3) of
    that grid; None if they are not."""
    pitch = float(np.min(hi - lo))
    ilo, ihi = np.rint(lo / pitch).astype(np.int64), np.rint(hi / pitch).astype(np.int64)
    if not (
        np.allclose(ilo * pitch, lo, rtol=0, atol=1e-6 * pitch)
        and np.allclose(ihi * pitch, hi, rtol=0, atol=1e-6 * pitch)
    ):
        return None
    return pitch, ilo, ihi


#: Most grid cells :func:`merged_voxel_boxes` expands voxel boxes into before it merges them.
MERGE_CELL_LIMIT = 20_000_000


def merged_voxel_boxes(voxel_boxes: np.ndarray) -> np.ndarray:
    """Fewer boxes (m, 2, 3) with the same union as ``voxel_boxes`` (n, 2, 3) ``[lo, hi]``, when
    those lie on one grid (:func:`_on_one_grid`: an OctoMap's leaves, its pruned ones 2, 4, ...
    voxels wide); boxes that do not, or cover more than :data:`MERGE_CELL_LIMIT` cells, come back
    as they are. A scanned office floor (geb079, 143,729 leaves) becomes 28,312 boxes, which fcl
    sets up in a third of the time. Corners are multiples of the pitch, so they move by float
    rounding only."""
    return by_voxel_content("merged", voxel_boxes, _merged_voxel_boxes).copy()


def _merged_voxel_boxes(vb: np.ndarray) -> np.ndarray:
    from secure3d.mapping.boxes import merge_cells

    grid = _on_one_grid(vb[:, 0], vb[:, 1]) if len(vb) > 1 else None
    if grid is None or np.prod(grid[2] - grid[1], axis=1).sum() > MERGE_CELL_LIMIT:
        return vb
    pitch, ilo, ihi = grid
    cells = _grid_cells(ilo, ihi)[0]
    # each cell once (merge_cells needs unique cells, and leaves given twice may overlap)
    base = cells.min(axis=0)
    dims = tuple(cells.max(axis=0) - base + 1)
    flat = np.ravel_multi_index(tuple((cells - base).T), dims)
    if int(np.prod(dims)) <= _DENSE_CELLS:  # a bitmap of the grid: cheaper than sorting
        seen = np.zeros(int(np.prod(dims)), bool)
        seen[flat] = True
        flat = np.flatnonzero(seen)
    else:
        flat = np.unique(flat)
    lo, hi = merge_cells(np.stack(np.unravel_index(flat, dims), -1) + base)
    return np.stack([lo * pitch, (hi + 1) * pitch], axis=1)


def exposed_sides(lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
    """(n, 6) bool: which sides (-x, +x, -y, +y, -z, +z) of grid-aligned boxes are not covered
    entirely by other boxes of the same set; None if the boxes are not cubes of one grid (whole
    multiples of the smallest edge, at multiples of it), as OctoMap leaves are.

    A ray from outside the boxes reaches a covered side only after crossing the surface of their
    union, which lies on exposed sides: dropping the covered ones leaves every first hit, and so
    every depth image, as it was."""
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    if not len(lo):
        return np.zeros((0, 6), bool)
    grid = _on_one_grid(lo, hi)
    if grid is None:
        return None
    _, ilo, ihi = grid
    base, span = ilo.min(axis=0) - 1, ihi.max(axis=0) - ilo.min(axis=0) + 3
    occupied = _occupancy(_grid_cells(ilo, ihi)[0] - base, span)
    exposed = np.zeros((len(lo), 6), bool)
    for axis in range(3):
        for sign in (0, 1):
            # the layer of cells just outside this side: one cell thick along the axis
            a, b = ilo.copy(), ihi.copy()
            if sign:
                a[:, axis], b[:, axis] = ihi[:, axis], ihi[:, axis] + 1
            else:
                a[:, axis], b[:, axis] = ilo[:, axis] - 1, ilo[:, axis]
            cells, owner = _grid_cells(a, b)
            free = ~occupied(cells - base)
            exposed[np.unique(owner[free]), 2 * axis + sign] = True
    return exposed


def box_trimesh(box: Box) -> trimesh.Trimesh:
    """A closed 12-triangle mesh of ``box`` (via :func:`trimesh.creation.box`)."""
    lo, hi = np.asarray(box.lo), np.asarray(box.hi)
    return trimesh.creation.box(bounds=np.stack([lo, hi]))


def obstacle_meshes(
    boxes: Sequence[Box] = (),
    meshes: Sequence[MeshObstacle] = (),
    voxel_boxes: np.ndarray | None = None,
) -> list[tuple[str, trimesh.Trimesh]]:
    """One ``(name, mesh)`` pair per obstacle, in the order boxes, meshes, voxels.

    Parameters
    ----------
    boxes : sequence of :class:`~secure3d.world.spec.Box`
    meshes : sequence of :class:`~secure3d.world.spec.MeshObstacle`
    voxel_boxes : (n, 2, 3) float, optional
        ``[lo, hi]`` of occupied voxels; all of them form one mesh named :data:`VOXEL_NAME`.
    """
    out = [(b.name, box_trimesh(b)) for b in boxes]
    out += [
        (m.name, trimesh.Trimesh(np.array(m.vertices), np.array(m.faces), process=False))
        for m in meshes
    ]
    if voxel_boxes is not None:
        vb = check_voxel_boxes(voxel_boxes)
        if len(vb):
            v, f = by_voxel_content("surface", vb, _voxel_surface)
            out.append((VOXEL_NAME, trimesh.Trimesh(v.copy(), f.copy(), process=False)))
    return out


def _voxel_surface(vb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of the voxel boxes ``vb`` (n, 2, 3): only the triangles a ray from
    outside can hit first, when the boxes lie on one grid."""
    v, f = box_arrays(vb[:, 0], vb[:, 1])
    sides = exposed_sides(vb[:, 0], vb[:, 1])
    if sides is not None:
        f = f[sides[:, _TRIANGLE_SIDE].reshape(-1)]
    return v, f


#: What the last few voxel worlds gave :func:`merged_voxel_boxes`, :func:`obstacle_meshes` and
#: the collision world's fcl shapes, by a digest of the voxel boxes: every flight of a campaign
#: over one scan sets up its collision world and camera from the same voxels (geb079: 0.5 s of a
#: 0.9 s set-up, 50 MB held), and the variants only add obstacles of their own. At most
#: CONTENT_CACHE_SIZE entries (three per world) and CONTENT_CACHE_BYTES in all: the least recently
#: used go first, and a value larger than the budget is not kept.
CONTENT_CACHE_SIZE = 12
CONTENT_CACHE_BYTES = 512 << 20


def _nbytes(value: object) -> int:
    """Memory a cached value holds, roughly: its arrays' bytes, 256 for any other object."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if isinstance(value, (tuple, list)):
        return sum(_nbytes(v) for v in value)
    return 256


def by_voxel_content(kind: str, vb: np.ndarray, build: Callable[[np.ndarray], object]) -> object:
    """``build(vb)`` for the voxel boxes ``vb`` (n, 2, 3), checked (:func:`check_voxel_boxes`), or
    what it gave for a ``kind`` of voxel boxes of the same bytes (BLAKE2b, 8 ms for the geb079
    scan's 143,729 leaves). ``build`` gets its own copy of ``vb``; what it returns is shared by
    every later call, so callers copy it or treat it as read-only.

    Raises
    ------
    GeometryError
        ``vb`` is not voxel boxes; ``kind`` is not a string or ``build`` not callable.
    """
    if not isinstance(kind, str) or not callable(build):
        raise GeometryError(
            f"by_voxel_content: kind must be a str and build callable, got {kind!r}"
        )
    data = np.ascontiguousarray(check_voxel_boxes(vb), dtype=float)
    key = (kind, data.shape, hashlib.blake2b(data.tobytes(), digest_size=20).digest())
    hit = _CONTENT.get(key)
    if hit is not None:
        return hit
    value = build(data.copy())  # never the caller's array: it may change after this call
    _CONTENT.put(key, value)
    return value


_CONTENT = BoundedCache(CONTENT_CACHE_SIZE, CONTENT_CACHE_BYTES, _nbytes)


def labelled_union(parts: Sequence[tuple[str, trimesh.Trimesh]]) -> trimesh.Trimesh:
    """Join ``(name, mesh)`` pairs into one unprocessed mesh that remembers the parts.

    Returns
    -------
    trimesh.Trimesh
        Faces keep their order. ``face_attributes["obstacle"]`` : (m,) int32 index into
        ``metadata["obstacle_names"]`` (tuple of str). No parts give a mesh with no faces.
    """
    names = tuple(name for name, _ in parts)
    if not parts:
        mesh = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), process=False)
        mesh.face_attributes["obstacle"] = np.zeros(0, dtype=np.int32)
        mesh.metadata["obstacle_names"] = names
        return mesh
    counts = np.array([len(m.vertices) for _, m in parts])
    offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
    vertices = np.concatenate([np.asarray(m.vertices, dtype=float) for _, m in parts])
    faces = np.concatenate(
        [np.asarray(m.faces) + off for (_, m), off in zip(parts, offsets, strict=True)]
    )
    labels = np.repeat(np.arange(len(parts), dtype=np.int32), [len(m.faces) for _, m in parts])
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    mesh.face_attributes["obstacle"] = labels
    mesh.metadata["obstacle_names"] = names
    return mesh


def world_trimesh(
    boxes: Sequence[Box] = (),
    meshes: Sequence[MeshObstacle] = (),
    voxel_boxes: np.ndarray | None = None,
) -> trimesh.Trimesh:
    """All obstacles as one labelled triangle mesh (see :func:`labelled_union`).

    Parameters are those of :func:`obstacle_meshes`.
    """
    return labelled_union(obstacle_meshes(boxes, meshes, voxel_boxes))
