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
