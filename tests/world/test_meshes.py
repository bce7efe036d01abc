"""Safe mesh loading: paths stay inside the scenario folder, files cannot pull in other files,
and only closed meshes with a positive volume are accepted."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh

from secure3d.errors import ScenarioError
from secure3d.world.meshes import MAX_MESH_FACES, load_mesh, mesh_from_arrays, resolve_inside


def test_resolve_inside(tmp_path: Path) -> None:
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "a.obj").write_text("x")
    (tmp_path.parent / f"{tmp_path.name}_sibling.obj").write_text("x")
    assert (
        resolve_inside(tmp_path, "sub/../sub/a.obj", "f") == (tmp_path / "sub" / "a.obj").resolve()
    )
    for ref, problem in [
        (f"../{tmp_path.name}_sibling.obj", "outside"),
        (str(tmp_path / "sub" / "a.obj"), "absolute"),
        ("sub", "no such file"),
        ("", "non-empty"),
        ("a\x00b", "NUL"),
    ]:
        with pytest.raises(ScenarioError, match=rf"^f: .*{problem}"):
            resolve_inside(tmp_path, ref, "f")


def test_obj_cannot_read_other_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    secret = tmp_path.parent / "secret.mtl"
    secret.write_text("newmtl leak\nKd 1 0 0\n")
    box = trimesh.creation.box((1, 1, 1))
    text = f"mtllib ../{secret.name}\n" + box.export(file_type="obj")
    path = tmp_path / "box.obj"
    path.write_text(text)

    def refuse(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("trimesh tried to resolve a referenced file")

    monkeypatch.setattr(trimesh.resolvers.FilePathResolver, "__init__", refuse)
    mesh = load_mesh(path, "box")
    np.testing.assert_allclose(mesh.lo, (-0.5, -0.5, -0.5), atol=1e-12)


@pytest.mark.parametrize("suffix", [".obj", ".stl", ".ply"])
def test_formats_and_placement(tmp_path: Path, suffix: str) -> None:
    cyl = trimesh.creation.cylinder(radius=0.5, height=2.0, sections=24)
    path = tmp_path / f"c{suffix}"
    cyl.export(path)
    mesh = load_mesh(path, "c", translate=(1.0, 2.0, 3.0), scale=2.0)
    np.testing.assert_allclose(mesh.lo, (-0.0, 1.0, 1.0), atol=1e-6)
    np.testing.assert_allclose(mesh.hi, (2.0, 3.0, 5.0), atol=1e-6)
    assert mesh.path == path and mesh.scale == 2.0 and mesh.translate == (1.0, 2.0, 3.0)
    volume = trimesh.Trimesh(mesh.vertices, mesh.faces).volume
    # STL stores float32 and OBJ 8 decimals: 1e-6 relative is the files' own precision.
    np.testing.assert_allclose(volume, cyl.volume * 8.0, rtol=1e-6, err_msg="scale^3 x volume")
    assert not mesh.vertices.flags.writeable


def test_mesh_from_arrays_checks() -> None:
    box = trimesh.creation.box((1, 2, 3))
    m = mesh_from_arrays(box.vertices, box.faces, "b")
    assert m.path is None
    with pytest.raises(ScenarioError, match="watertight"):
        mesh_from_arrays(box.vertices, box.faces[:-1], "b")
    with pytest.raises(ScenarioError, match="positive volume"):
        mesh_from_arrays(box.vertices, box.faces[:, ::-1], "b")
    with pytest.raises(ScenarioError, match="indices"):
        mesh_from_arrays(box.vertices, box.faces + 100, "b")
    with pytest.raises(ScenarioError, match=r"\(n, 3\)"):
        mesh_from_arrays(box.vertices[:, :2], box.faces, "b")
    many = np.zeros((MAX_MESH_FACES + 1, 3), dtype=int)
    with pytest.raises(ScenarioError, match="triangles"):
        mesh_from_arrays(box.vertices, many, "b")
