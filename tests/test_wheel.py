"""The wheel works alone: built from this tree, installed into a fresh virtual environment, and
run from another directory, with no checkout and no maps/ folder in sight."""

from __future__ import annotations

import os
import subprocess
import sys
import venv
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _pip_env(original_env: dict[str, str], home: Path) -> dict[str, str]:
    """pip with the real download cache (the suite's HOME is a sandbox), everything else fresh."""
    cache_home = original_env.get("XDG_CACHE_HOME") or os.path.join(
        original_env.get("HOME", str(home)), ".cache"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV"))}
    env["PIP_CACHE_DIR"] = original_env.get("PIP_CACHE_DIR") or os.path.join(cache_home, "pip")
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    env["HOME"] = str(home)
    return env


def _run(cmd: list[str], env: dict[str, str], cwd: Path, timeout: float) -> str:
    done = subprocess.run(
        cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout, check=False
    )
    assert done.returncode == 0, f"{cmd[:3]} exit {done.returncode}:\n{done.stderr[-2000:]}"
    return done.stdout


@pytest.mark.slow
def test_the_wheel_installs_into_a_fresh_venv_and_flies_the_demo(tmp_path, original_env):
    env = _pip_env(original_env, tmp_path / "home")
    dist = tmp_path / "dist"
    _run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist), str(REPO)],
        env,
        tmp_path,
        600,
    )
    (wheel,) = dist.glob("secure3d-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for shipped in ("secure3d/maps/blind_corner.yaml", "secure3d/maps/octomaps/geb079.bt"):
        assert shipped in names, shipped
    assert any(n.endswith("licenses/LICENSE") for n in names)
    assert not any(n.startswith("secure3d/maps/generate") for n in names)

    target = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True).create(target)
    python = target / "bin" / "python"
    _run([str(python), "-m", "pip", "install", "-q", str(wheel)], env, tmp_path, 900)

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    cli = str(target / "bin" / "secure3d")
    assert "bench" not in _run([cli, "--help"], env, elsewhere, 60)  # no benchmark scripts here
    assert "blind_corner" in _run([cli, "show", "blind_corner"], env, elsewhere, 120)
    out = _run([cli, "demo", "--quick", "--out", "demo"], env, elsewhere, 900)
    assert "secure" in out and "reached goal" in out, out[-2000:]
    for name in (
        "blind_corner_secure.rrd",
        "blind_corner_baseline.rrd",
        "blind_corner_top_down.png",
    ):
        assert (elsewhere / "demo" / name).stat().st_size > 0, name
    assert not list((elsewhere / "demo").glob("*.part"))
