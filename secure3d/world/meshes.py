"""Safe loading of mesh obstacles (OBJ / STL / PLY) for scenarios.

Scenario files come from users and may be hostile or broken, so loading is deliberately narrow:

- the path must resolve (after ``..`` and symlinks) inside the scenario's folder
  (:func:`resolve_inside`);
- the file is read as bytes with a size cap and handed to trimesh as an in-memory buffer without a
  resolver, so an OBJ cannot make trimesh open other files (``mtllib ../../secret``);
- the result must be a closed, consistently wound triangle mesh with positive volume
  (``is_volume``) and finite coordinates: the simulator ray-casts it and the collision checker
  needs an inside.

Every failure is a :class:`~secure3d.errors.ScenarioError` naming the file.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.world.spec import MeshObstacle, Vec3

#: Largest mesh file we read (bytes). Scenario meshes are obstacles, not scans: 20 MB is plenty.
MAX_MESH_BYTES = 20_000_000
#: Largest triangle count per mesh. The simulator ray-casts every mesh each frame; 200k triangles
#: already costs ~20x the 10k-triangle benchmark in DESIGN.md section 5.
MAX_MESH_FACES = 200_000
MESH_SUFFIXES = (".obj", ".stl", ".ply")


def resolve_inside(folder: Path, relative: str | os.PathLike[str], what: str) -> Path:
    """Resolve ``relative`` against ``folder`` and check the result stays inside it.

    Parameters
    ----------
    folder : Path
        The scenario's folder (the directory holding the YAML file).
    relative : str or PathLike
        A path relative to ``folder``. Absolute paths are refused.
    what : str
        Field path used in error messages, e.g. ``"world.meshes[0].file"``.

    Returns
    -------
    Path
        The absolute, symlink-free path of an existing regular file inside ``folder``.

    Raises
    ------
    ScenarioError
        If the path is absolute, escapes ``folder`` (via ``..`` or a symlink), does not exist or is
        not a regular file. The message starts with ``what``.
    """
    text = os.fspath(relative)
    if not isinstance(text, str) or not text.strip():
        raise ScenarioError(f"{what}: must be a non-empty relative path (got {relative!r})")
    if "\x00" in text:
        raise ScenarioError(f"{what}: contains a NUL byte (got {relative!r})")
    if Path(text).is_absolute():
        raise ScenarioError(
            f"{what}: must be relative to the scenario's folder, not absolute (got {text!r})"
        )
    root = Path(folder).resolve()
    target = (root / text).resolve()
    if not target.is_relative_to(root):
        raise ScenarioError(f"{what}: resolves outside the scenario's folder {root} (got {text!r})")
    if not target.is_file():
        raise ScenarioError(f"{what}: no such file {target} (got {text!r})")
    return target


def load_mesh(
    path: Path,
    name: str,
    *,
    translate: Vec3 = (0.0, 0.0, 0.0),
    scale: float = 1.0,
    what: str | None = None,
) -> MeshObstacle:
    """Load a closed triangle mesh and place it in the world.

    World vertices are ``scale * v_file + translate``.

    Parameters
    ----------
    path : Path
        An OBJ, STL or PLY file (already checked by :func:`resolve_inside` when it comes from a
        scenario file).
    name : str
        Obstacle name.
    translate : (3,) float
        Offset added after scaling (m).
    scale : float
        Uniform scale factor, > 0.
    what : str, optional
        Field path for error messages; defaults to ``mesh <name>``.

    Returns
    -------
    MeshObstacle
        With ``vertices : (n, 3) float`` and ``faces : (m, 3) int`` read-only.

    Raises
    ------
    ScenarioError
        Unreadable, too large, empty, not closed or of zero volume; the message names the file.
    """
    import trimesh

    what = what or f"mesh {name!r}"
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise ScenarioError(
            f"{what}: mesh files must be {', '.join(MESH_SUFFIXES)} (got {path.name!r})"
        )
    try:
        size = path.stat().st_size
        if size > MAX_MESH_BYTES:
            raise ScenarioError(
                f"{what}: {path} is larger than {MAX_MESH_BYTES // 1_000_000} MB (got {size} bytes)"
            )
        data = path.read_bytes()
    except OSError as exc:
        raise ScenarioError(f"{what}: cannot read {path}: {exc.strerror or exc}") from None
    try:
        raw = trimesh.load(
            io.BytesIO(data), file_type=suffix[1:], force="mesh", resolver=None, process=False
        )
    except Exception as exc:  # noqa: BLE001 - any parser failure means a broken file
        detail = " ".join(str(exc).split())[:120] or type(exc).__name__
        raise ScenarioError(f"{what}: cannot parse {path}: {detail}") from None
    # Before trimesh's processing, which drops NaN vertices and so made them "not watertight".
    _check_finite(getattr(raw, "vertices", np.zeros((0, 3))), f"{what}: {path}")
    mesh = trimesh.Trimesh(raw.vertices, raw.faces, process=True) if len(raw.faces) else raw
    vertices, faces = _checked(mesh, f"{what}: {path}")
    vertices = vertices * scale + np.asarray(translate, dtype=float)
    return MeshObstacle(name, vertices, faces, path, translate, scale)


def mesh_from_arrays(
    vertices: object, faces: object, name: str, *, what: str | None = None
) -> MeshObstacle:
    """Build a mesh obstacle from inline arrays, with the same checks as :func:`load_mesh`.

    Parameters
    ----------
    vertices : (n, 3) float
        World coordinates (m).
    faces : (m, 3) int
        Vertex indices of each triangle, counter-clockwise seen from outside.
    name : str
    what : str, optional
        Field path for error messages.

    Returns
    -------
    MeshObstacle
        With ``path=None``.
    """
    import trimesh

    what = what or f"mesh {name!r}"
    try:
        v = np.asarray(vertices, dtype=float)
        f = np.asarray(faces)
    except (TypeError, ValueError):
        raise ScenarioError(f"{what}: vertices/faces must be numeric arrays") from None
    if v.ndim != 2 or v.shape[1] != 3 or f.ndim != 2 or f.shape[1] != 3:
        raise ScenarioError(
            f"{what}: vertices and faces must be (n, 3) arrays (got {v.shape} and {f.shape})"
        )
    if not np.issubdtype(f.dtype, np.integer) or (f.size and (f.min() < 0 or f.max() >= len(v))):
        raise ScenarioError(f"{what}.faces: must be integer indices into the {len(v)} vertices")
    if len(f) > MAX_MESH_FACES:
        raise ScenarioError(f"{what}: more than {MAX_MESH_FACES} triangles (got {len(f)})")
    _check_finite(v, what)
    mesh = trimesh.Trimesh(v, f, process=True)
    v, f = _checked(mesh, what)
    return MeshObstacle(name, v, f)


def _check_finite(vertices: object, what: str) -> None:
    v = np.asarray(vertices, dtype=float)
    bad = ~np.all(np.isfinite(v), axis=1) if v.ndim == 2 else np.zeros(0, bool)
    if bad.any():
        raise ScenarioError(
            f"{what}: {int(bad.sum())} vertices with NaN or infinite coordinates"
            f" (first: vertex {int(np.argmax(bad))})"
        )


def _checked(mesh: object, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of ``mesh`` if it is a closed, finite, positive-volume triangle mesh."""
    import trimesh

    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ScenarioError(f"{what}: holds no triangles")
    if len(mesh.faces) > MAX_MESH_FACES:
        raise ScenarioError(f"{what}: more than {MAX_MESH_FACES} triangles (got {len(mesh.faces)})")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ScenarioError(f"{what}: NaN or infinite vertex coordinates")
    if not mesh.is_watertight:
        raise ScenarioError(f"{what}: not a closed (watertight) mesh")
    if not mesh.is_volume or not mesh.volume > 0:
        raise ScenarioError(
            f"{what}: does not bound a positive volume (inconsistent winding or degenerate)"
        )
    return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)
