"""secure3d's numba kernels are cached in the user's cache directory, keyed by their sources."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import secure3d
from secure3d import _numba_cache

PACKAGE = Path(secure3d.__file__).resolve().parent


def test_every_kernel_module_registers_the_cache_locator():
    for path in PACKAGE.rglob("*.py"):
        text = path.read_text()
        if "njit(" in text and "cache=True" in text:
            assert "import secure3d._numba_cache" in text, path


def test_kernels_use_the_user_cache_keyed_by_source_digest():
    from secure3d.geometry import _box_index_kernels

    locator = _box_index_kernels.build._cache._impl.locator
    assert type(locator).__name__ == "Secure3dCacheLocator"
    path = Path(locator.get_cache_path())
    assert (
        path == _numba_cache.cache_root() / _numba_cache.kernel_digest() / "secure3d" / "geometry"
    )
    assert locator.get_source_stamp() == _numba_cache.kernel_digest()


def test_cache_root_respects_the_environment(tmp_path):
    code = "from secure3d._numba_cache import cache_root; print(cache_root())"
    drop = ("SECURE3D_NUMBA_CACHE_DIR", "SECURE3D_CACHE_DIR")
    env = {k: v for k, v in os.environ.items() if k not in drop}
    env["XDG_CACHE_HOME"] = str(tmp_path / "xdg")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert Path(out.stdout.strip()) == tmp_path / "xdg" / "secure3d" / "numba"
    env["SECURE3D_CACHE_DIR"] = str(tmp_path / "shared")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert Path(out.stdout.strip()) == tmp_path / "shared" / "numba"
    env["SECURE3D_NUMBA_CACHE_DIR"] = str(tmp_path / "explicit")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert Path(out.stdout.strip()) == tmp_path / "explicit"
