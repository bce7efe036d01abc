"""Solves do not depend on the BLAS thread count of the machine or the user's environment."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from secure3d.errors import ConfigError
from secure3d.planning.blas import ENV, blas_threads, pin_blas_threads

REPO = Path(__file__).resolve().parents[2]

_PLAN = """
import json, secure3d
from secure3d.planning.blas import blas_threads
from secure3d.world.scenario import load_scenario
s = load_scenario({path!r})
r = secure3d.plan(s, "secure")
print(json.dumps([r.status.name, r.final_time, blas_threads()]))
"""


def _plan_in_new_process(scenario: Path, openblas_threads: str) -> list:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": openblas_threads}
    env.pop(ENV, None)
    out = subprocess.run(
        [sys.executable, "-c", _PLAN.format(path=str(scenario))],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("name", ["planar_blind_corner", "paper_blind_corner"])
def test_a_diff_drive_plan_is_the_same_with_one_or_two_openblas_threads(maps_dir, name):
    """planar_blind_corner's secure solve ended in another local minimum with 2 threads
    (T 5.35 s against 4.53 s) before the planner pinned CasADi's OpenBLAS."""
    one = _plan_in_new_process(maps_dir / f"{name}.yaml", "1")
    two = _plan_in_new_process(maps_dir / f"{name}.yaml", "2")
    assert one[0] == two[0] == "SUCCESS"
    assert one[1] == two[1]  # bit for bit
    assert one[2] == two[2] == 1


def test_pin_blas_threads_sets_and_validates(monkeypatch):
    before = blas_threads()
    try:
        assert pin_blas_threads(2) == 2 and blas_threads() == 2
        monkeypatch.setenv(ENV, "1")
        assert pin_blas_threads() == 1
        monkeypatch.setenv(ENV, "zero")
        with pytest.raises(ConfigError, match=ENV):
            pin_blas_threads()
        with pytest.raises(ConfigError, match="positive integer"):
            pin_blas_threads(0)
    finally:
        pin_blas_threads(max(before, 1))
