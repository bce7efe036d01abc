"""The package's face: exports listed and typed, one version, a licence."""

from __future__ import annotations

import importlib.metadata
import tomllib
from pathlib import Path

import secure3d

REPO = Path(__file__).resolve().parents[1]


def test_dir_lists_the_lazy_exports():
    names = dir(secure3d)
    for name in ("load_scenario", "plan", "certify", "simulate", "OccupancyMap", "__version__"):
        assert name in names, name
    assert secure3d.plan.__module__ == "secure3d.planning.solve"


def test_the_version_is_written_once():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert "version" not in project and "version" in project["dynamic"]
    assert importlib.metadata.version("secure3d") == secure3d.__version__
    assert (REPO / "LICENSE").read_text().startswith("BSD 3-Clause License")


def test_scenarios_load_by_name_from_the_package(tmp_path, monkeypatch):
    from secure3d.errors import ScenarioError
    from secure3d.world.bundled import bundled_dir, bundled_names

    monkeypatch.chdir(tmp_path)  # nowhere near the repository's maps/
    assert {"blind_corner", "forest", "thin_pole"} <= set(bundled_names())
    assert secure3d.load_scenario("blind_corner").name == "blind_corner"
    assert secure3d.load_scenario("forest.yaml").name == "forest"
    assert (bundled_dir() / "octomaps" / "geb079.bt").is_file()
    try:
        secure3d.load_scenario("no_such_scenario")
    except ScenarioError as exc:
        assert "no_such_scenario" in str(exc) and "blind_corner" in str(exc)
    else:
        raise AssertionError("an unknown name loaded")
    # a file in the working directory wins over a shipped scenario of the same name
    (tmp_path / "forest.yaml").write_text("name: [")
    try:
        secure3d.load_scenario("forest.yaml")
    except ScenarioError as exc:
        assert "YAML error" in str(exc)
    else:
        raise AssertionError("the shipped forest was taken instead of the local file")


def test_make_warm_flies_one_shipped_scenario_of_each_other_vehicle():
    """``secure3d.warm.WARM_FLIGHTS`` compiles the node kernels of every shipped vehicle: each
    names a scenario in ``maps/``, and together with the blind corner they cover every model the
    shipped scenarios fly."""
    from secure3d.warm import WARM_FLIGHTS
    from secure3d.world import load_scenario

    models = {load_scenario(REPO / "maps" / name).vehicle.model for name in WARM_FLIGHTS}
    models.add(load_scenario(REPO / "maps" / "blind_corner.yaml").vehicle.model)
    shipped = {load_scenario(p).vehicle.model for p in sorted((REPO / "maps").glob("*.yaml"))}
    assert shipped <= models, shipped - models
