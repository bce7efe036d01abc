"""Shared fixtures. Keeps Rerun/matplotlib from writing into the real HOME during tests."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

#: The environment as pytest was started, before the sandbox below (the wheel test reuses pip's
#: real cache from it).
ORIGINAL_ENV = dict(os.environ)
# numba's compiled kernels stay in the user's cache (where `make venv` compiled them), not in the
# sandbox: a sandboxed cache would recompile every kernel (10-20 s) in every test session.
from secure3d._numba_cache import cache_root  # noqa: E402

os.environ.setdefault("SECURE3D_NUMBA_CACHE_DIR", str(cache_root()))
# The kernels' derivatives run in CasADi's VM unless a test asks for compiled ones
# (tests/planning/test_compiled_kernels.py): the values are the same bit for bit, and a sandboxed
# cache would compile every kernel shape of the suite again in every session.
os.environ.setdefault("SECURE3D_KERNEL_COMPILE", "off")
_SANDBOX_HOME = Path(tempfile.mkdtemp(prefix="secure3d-test-home-"))
for _var in ("HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME", "XDG_CACHE_HOME", "MPLCONFIGDIR"):
    os.environ[_var] = str(_SANDBOX_HOME / _var.lower())
    Path(os.environ[_var]).mkdir(parents=True, exist_ok=True)
os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MAPS = REPO / "maps"
#: The real OctoMap files the tests read: ``$SECURE3D_SHARED_OCTOMAP`` if set, else the project's
#: shared data beside the repository, else the copies in tests/data/octomap (the same files, with
#: OctoMap's licence; geb079.bt links to maps/octomaps), so that a bare clone runs every test.
_OCTOMAP_DIRS = [REPO.parent / "shared" / "data" / "octomap", REPO / "tests" / "data" / "octomap"]
SHARED_OCTOMAP = Path(
    os.environ.get("SECURE3D_SHARED_OCTOMAP")
    or next((d for d in _OCTOMAP_DIRS if d.is_dir()), _OCTOMAP_DIRS[-1])
)


@pytest.fixture
def rng() -> np.random.Generator:
    """A seeded generator: every random test is reproducible."""
    return np.random.default_rng(0)


@pytest.fixture(scope="session")
def maps_dir() -> Path:
    return MAPS


@pytest.fixture(scope="session")
def octomap_dir() -> Path:
    """The real OctoMap files (:data:`SHARED_OCTOMAP`; skips nothing: they must exist)."""
    if not SHARED_OCTOMAP.is_dir():
        raise FileNotFoundError(f"shared OctoMap data not found at {SHARED_OCTOMAP}")
    return SHARED_OCTOMAP


@pytest.fixture(scope="session")
def original_env() -> dict[str, str]:
    """The environment pytest started with, before this file sandboxed HOME and the caches."""
    return dict(ORIGINAL_ENV)


#: A 6 m x 3 m room with one wall to go around (campaign and CLI tests).
TINY_ROOM = Path(__file__).resolve().parent / "data" / "tiny_room.yaml"


@pytest.fixture(scope="module")
def benchmark_module():
    """A loader of ``benchmarks/`` scripts by module name, with benchmarks/ on ``sys.path`` and its
    own ``_common`` (examples/ has a ``_common`` too, which an earlier test in the same process may
    have imported); ``sys.path`` and ``sys.modules`` are as they were afterwards."""
    import importlib
    import sys

    saved_path = list(sys.path)
    saved = {n: sys.modules.pop(n) for n in ("_common",) if n in sys.modules}
    sys.path.insert(0, str(REPO / "benchmarks"))
    loaded: list[str] = []

    def load(name: str):
        loaded.append(name)
        return importlib.import_module(name)

    try:
        yield load
    finally:
        sys.path[:] = saved_path
        for n in ("_common", *loaded):
            sys.modules.pop(n, None)
        sys.modules.update(saved)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A copy of ``tests/data/tiny_room.yaml`` in a fresh folder (outputs may land beside it)."""
    path = tmp_path_factory.mktemp("scenarios") / "tiny.yaml"
    path.write_text(TINY_ROOM.read_text())
    return path


@pytest.fixture(scope="session")
def octomap_voxels():
    """``count(tree) -> (occupied, free)`` voxels of an octomap-python tree (OctoMap prunes equal
    siblings: a leaf at depth d stands for 8**(16 - d) voxels)."""

    def count(tree: object) -> tuple[int, int]:
        n_occ = n_free = 0
        for leaf in tree.begin_leafs():
            n = 8 ** (16 - leaf.getDepth())
            if tree.isNodeOccupied(leaf):
                n_occ += n
            else:
                n_free += n
        return n_occ, n_free

    return count


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Modules with a slow test first (a stable sort, each module's tests kept together, so that
    no module-scoped fixture is set up twice): under ``pytest -n`` (``make test``) the longest
    tests then start early and do not leave one worker busy alone at the end."""
    slow = {item.path for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.path not in slow)
