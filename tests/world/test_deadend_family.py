"""The dead-end family, called directly (issue 16): a hidden wall closes the shortest route."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import secure3d
from secure3d.errors import ScenarioError
from secure3d.world.attacks import server_claim
from secure3d.world.deadend_families import DEAD_END, THICKNESS
from secure3d.world.families import variant_rng
from secure3d.world.family_registry import FAMILIES
from secure3d.world.hidden_obstacles import _connected
from secure3d.world.spec import box_distance


def test_walls_close_the_route_keep_another_and_are_pure(maps_dir):
    base = secure3d.load_scenario(maps_dir / "planar_dead_end.yaml")
    assert FAMILIES["deadend"] is DEAD_END
    prep = DEAD_END.prepare(base)
    r = base.vehicle.body_radius
    lo_b, hi_b = base.world.bounds.lo, base.world.bounds.hi
    for i in range(5):
        v = DEAD_END.variant(prep, base, variant_rng(3, i), i)
        assert v == DEAD_END.variant(prep, base, variant_rng(3, i), i)
        box = v.world.boxes[-1]
        assert len(v.world.boxes) == len(base.world.boxes) + 1
        assert box.name in v.hidden_obstacles
        assert box.name not in {b.name for b in server_claim(v).boxes}
        lo, hi = np.array(box.lo), np.array(box.hi)
        # as tall as the world, THICKNESS thick across the path, and cutting the old route
        assert lo[2] == lo_b[2] and hi[2] == hi_b[2]
        assert THICKNESS[0] - 1e-9 <= (hi - lo)[:2].min() <= THICKNESS[1] + 1e-9
        assert box_distance(lo[None], hi[None], prep.path, prep.path).min() < r
        # the old shortest path is blocked, but the goal is still reachable another way
        blocked = prep.grid.blocked_by(lo[None], hi[None]) & prep.grid.free
        assert _connected(blocked, prep.start_cell, prep.goal_cell)
        cells = np.round((prep.path - prep.grid.origin) / prep.grid.cell).astype(int)
        assert not blocked[tuple(np.clip(cells, 0, np.array(blocked.shape) - 1).T)].all()
    assert DEAD_END.variant(prep, base, variant_rng(4, 0), 0) != DEAD_END.variant(
        prep, base, variant_rng(3, 0), 0
    )


def test_a_base_with_one_route_is_refused_by_name_once_when_the_family_is_prepared(maps_dir):
    base = secure3d.load_scenario(maps_dir / "planar_blind_corner.yaml")
    with pytest.raises(
        ScenarioError, match="planar_blind_corner.*needs a base with a second route"
    ):
        DEAD_END.prepare(base)


def test_a_campaign_over_a_single_route_base_stops_before_any_run_with_one_line(maps_dir, tmp_path):
    """It wrote one identical error row per variant (300 placement attempts each), exit 0."""
    out = tmp_path / "camp"
    cmd = [sys.executable, "-m", "secure3d", "campaign", str(maps_dir / "narrow_passage_20cm.yaml")]
    cmd += ["-n", "3", "--kind", "deadend", "--out", str(out), "--no-progress"]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, (done.returncode, done.stderr)
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and "narrow_passage_20cm" in lines[0], done.stderr
    assert "second route" in lines[0] and "Traceback" not in done.stderr
    assert not out.exists()  # nothing half-made
