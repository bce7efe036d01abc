"""Hostile scenario files: bounded memory and time, one-line errors, no path tricks."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from secure3d.errors import ScenarioError
from secure3d.world.scenario import load_scenario

REPO = Path(__file__).resolve().parents[2]


def _alias_bomb(levels: int = 9, width: int = 9) -> str:
    """``[&a0 [1, ...], &a1 [*a0, ...], ...]``: a few hundred bytes, width**levels values."""
    items = ["&a0 [" + ", ".join(["1"] * width) + "]"]
    for k in range(1, levels):
        items.append(f"&a{k} [" + ", ".join([f"*a{k - 1}"] * width) + "]")
    return "[" + ", ".join(items) + "]"


def _with_limits(maps_dir: Path, tmp_path: Path, limits: str, name: str = "bomb") -> Path:
    text = (maps_dir / "blind_corner.yaml").read_text()
    text = text.replace("limits: {max_accel: 4.0, max_speed: 4.0}", f"limits: {limits}")
    assert f"limits: {limits}" in text
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return path


# VmHWM is this process image's own peak: ru_maxrss would carry the forking pytest's (1.5 GB in
# the full suite) across the exec.
_SHOW_AND_PEAK = """
import re, sys
from secure3d.cli import main
code = main(["show", sys.argv[1]])
status = open("/proc/self/status").read()
print("PEAK_KB", re.search(r"VmHWM:\\s*(\\d+)", status).group(1))
sys.exit(code)
"""


def test_a_yaml_alias_bomb_is_refused_in_bounded_memory_and_time(maps_dir, tmp_path):
    """Under a known key, the bomb used to drive `secure3d show` past 2.5 GB (error message repr)."""
    path = _with_limits(maps_dir, tmp_path, "{max_accel: " + _alias_bomb() + "}")
    assert path.stat().st_size < 5000
    run = subprocess.run(
        [sys.executable, "-c", _SHOW_AND_PEAK, str(path)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2, run.stderr[-500:]
    err = run.stderr.strip().splitlines()
    assert len(err) == 1 and "aliases" in err[0], err
    peak_kb = int(run.stdout.split("PEAK_KB")[-1])
    assert peak_kb < 500_000, f"peak RSS {peak_kb} kB (a plain show peaks near 140 MB)"


def test_a_self_referencing_alias_is_refused(maps_dir, tmp_path):
    path = _with_limits(maps_dir, tmp_path, "{max_accel: &a [1, *a]}")
    with pytest.raises(ScenarioError, match="recursive|contains it"):
        load_scenario(path)


def test_a_wide_but_legal_yaml_alias_use_still_loads(maps_dir, tmp_path):
    """Aliases themselves are fine: a shared 3-vector used twice loads."""
    text = (maps_dir / "blind_corner.yaml").read_text()
    assert load_scenario(maps_dir / "blind_corner.yaml").name == "blind_corner"
    path = tmp_path / "aliases.yaml"
    path.write_text("# shared\n" + text)
    assert load_scenario(path).name == "blind_corner"


@pytest.mark.parametrize("name", ["../../../X", "a/b", "..", ".hidden", "a\\b", "x" * 121, "a b"])
def test_a_scenario_name_that_is_no_safe_file_name_is_refused(maps_dir, tmp_path, name):
    text = (
        (maps_dir / "blind_corner.yaml")
        .read_text()
        .replace("name: blind_corner", f"name: {name!r}".replace("'", '"'), 1)
    )
    path = tmp_path / "named.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match="name: must be 1-120 letters"):
        load_scenario(path)


def test_error_messages_show_a_bounded_repr():
    from secure3d.world.spec import _short

    deep: list = [1]
    for _ in range(30):
        deep = [deep] * 50
    text = _short(deep)
    assert len(text) <= 60 and text.startswith("[[")
