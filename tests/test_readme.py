"""README's Python quick start runs as written (from the repository root, as README says)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_the_python_quick_start_runs_as_written(tmp_path):
    readme = (REPO / "README.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", readme, flags=re.S)
    assert blocks, "README has no python block"
    quick = blocks[0]
    assert "simulate(" in quick and "out/" in quick
    # out/ is where README writes; run it with out/ pointing into tmp_path, from the repo root
    code = quick.replace('"out/', f'"{tmp_path}/out/')
    run = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=600
    )
    assert run.returncode == 0, run.stderr[-2000:]
    assert (tmp_path / "out" / "run.rrd").is_file() and (tmp_path / "out" / "run.png").is_file()
    assert "CERTIFIED" in run.stdout


def _quick_start_shell_lines(readme: str) -> list[str]:
    section = readme.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    (block,) = re.findall(r"```bash\n(.*?)```", section, flags=re.S)
    return [line.split("#", 1)[0].strip() for line in block.splitlines() if line.strip()]


def test_the_shell_quick_start_runs_as_written(tmp_path):
    """Each `secure3d` line runs from the repository root (out/ redirected into tmp_path); the
    viewer line is not opened, but the file it names must exist."""
    lines = _quick_start_shell_lines((REPO / "README.md").read_text())
    viewer = [line for line in lines if line.startswith(".venv/bin/rerun ")]
    commands = [line for line in lines if line.startswith(".venv/bin/secure3d ")]
    assert commands and viewer and len(commands) + len(viewer) == len(lines), lines
    for line in commands:
        argv = line.replace("out/", f"{tmp_path}/out/").split()[1:]
        run = subprocess.run(
            [sys.executable, "-m", "secure3d", *argv],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert run.returncode == 0, (line, run.stderr[-2000:])
    for line in viewer:
        recording = tmp_path / line.split()[1]
        assert recording.is_file() and recording.stat().st_size > 0, recording


def test_every_relative_link_in_readme_exists():
    readme = (REPO / "README.md").read_text()
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", readme)
    local = [link for link in links if not link.startswith(("http://", "https://"))]
    assert "docs/img/blind_corner.png" in local
    missing = [link for link in local if not (REPO / link).exists()]
    assert not missing, missing


def test_the_paper_to_code_map_names_real_objects():
    import importlib

    readme = (REPO / "README.md").read_text()
    section = readme.split("## Architecture", 1)[1].split("\n## ", 1)[0]
    names = re.findall(r"`(secure3d(?:\.\w+)+)`", section)
    assert len(names) >= 20, names
    for name in names:
        parts = name.split(".")
        for cut in range(len(parts), 0, -1):  # the longest importable module, then attributes
            try:
                obj = importlib.import_module(".".join(parts[:cut]))
            except ModuleNotFoundError:
                continue
            for attr in parts[cut:]:
                obj = getattr(obj, attr)
            break
        else:
            raise AssertionError(f"{name} does not resolve")
