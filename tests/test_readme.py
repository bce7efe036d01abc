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
