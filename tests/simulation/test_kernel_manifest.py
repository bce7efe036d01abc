"""No numba kernel is loaded or compiled for the first time inside a flight: the set-up preloads
what earlier flights called (:mod:`secure3d._kernel_manifest`)."""

from __future__ import annotations

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba import types

from secure3d import _kernel_manifest as km

REPO = Path(__file__).resolve().parents[2]

_FLY = """
import json, sys
from numba.core import dispatcher
import secure3d
from secure3d.simulation import flight

calls = {"in_flight": [], "preloaded": []}
inside = [False]
compile_ = dispatcher.Dispatcher.compile
def counted(self, sig):
    if inside[0] and sig not in self.overloads:
        calls["in_flight"].append(self.py_func.__name__)
    return compile_(self, sig)
dispatcher.Dispatcher.compile = counted
run_ = flight.Flight.run
def run(self):
    calls["preloaded"].append(self.loop.kernels_preloaded)
    inside[0] = True
    try:
        return run_(self)
    finally:
        inside[0] = False
flight.Flight.run = run
outcomes = [secure3d.simulate(f"maps/{name}.yaml", "secure").outcome for name in sys.argv[1:]]
print(json.dumps({**calls, "outcomes": outcomes}))
"""


def _fly(manifest: Path, *names: str) -> dict:
    env = dict(os.environ, SECURE3D_KERNEL_MANIFEST=str(manifest))
    done = subprocess.run(
        [sys.executable, "-c", _FLY, *names],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_a_new_process_loads_every_kernel_its_flights_call_before_take_off(tmp_path):
    manifest = tmp_path / "kernels.pickle"
    names = ("blind_corner", "planar_blind_corner")  # point mass and diff drive
    first = _fly(manifest, *names)
    # nothing recorded yet: the first process loads its kernels in flight, as before
    assert first["preloaded"][0] == 0 and first["in_flight"], first
    recorded = pickle.loads(manifest.read_bytes())
    assert sum(len(s) for s in recorded.values()) >= 10, recorded.keys()
    second = _fly(manifest, *names)
    assert second["outcomes"] == first["outcomes"]
    assert second["preloaded"][0] >= len(set(first["in_flight"])), (first, second)
    assert second["in_flight"] == [], second["in_flight"]


def _some_kernel_loaded() -> None:
    from secure3d.mapping.morton import morton_encode

    morton_encode(np.zeros((2, 3), np.int64))


def test_record_adds_only_what_is_new_and_preload_skips_stale_entries(tmp_path):
    _some_kernel_loaded()
    path = tmp_path / "m.pickle"
    assert km.record(path) > 0
    stamp = path.stat().st_mtime_ns
    assert km.record(path) == 0 and path.stat().st_mtime_ns == stamp  # nothing new: not rewritten
    assert km.preload(path) == 0  # all loaded in this process already
    recorded = pickle.loads(path.read_bytes())
    added = {
        ("secure3d.no_such_module", "k"): {(types.int64,)},
        ("secure3d.mapping.morton", "no_such_kernel"): {(types.int64,)},
        ("os", "getcwd"): {()},  # not secure3d's: never imported from a manifest
        ("secure3d.mapping.morton", "_box_codes_kernel"): {(types.unicode_type,)},
    }
    path.write_bytes(pickle.dumps({**recorded, **added}))
    assert km.preload(path) == 0
    # the stale entries of secure3d are dropped, so no later set-up tries them again
    kept = pickle.loads(path.read_bytes())
    assert ("secure3d.no_such_module", "k") not in kept
    assert ("secure3d.mapping.morton", "no_such_kernel") not in kept
    assert (types.unicode_type,) not in kept.get(
        ("secure3d.mapping.morton", "_box_codes_kernel"), set()
    )
    assert kept[("os", "getcwd")] == {()}
    # the valid ones stay (the entries added above replaced whatever their keys held)
    want = {k: v for k, v in recorded.items() if k not in added}
    assert {k: v for k, v in kept.items() if k[0] != "os"} == want
    stamp = path.stat().st_mtime_ns
    assert km.preload(path) == 0
    assert path.stat().st_mtime_ns == stamp  # nothing stale any more: not rewritten


def test_a_corrupt_or_unwritable_manifest_changes_nothing_but_speed(tmp_path):
    _some_kernel_loaded()
    path = tmp_path / "m.pickle"
    path.write_bytes(b"\x80\x04 not a pickle")
    assert km.preload(path) == 0
    assert km.record(path) > 0  # rewritten whole
    assert pickle.loads(path.read_bytes())
    blocked = tmp_path / "file"
    blocked.write_text("x")
    assert km.record(blocked / "m.pickle") == 0  # its folder is a file: nothing written, no error
    assert not list(tmp_path.glob("*.part")) and not list(tmp_path.glob(".*.part"))


def test_the_manifest_lives_with_the_kernel_cache_unless_named(monkeypatch, tmp_path):
    monkeypatch.delenv(km.MANIFEST_ENV, raising=False)
    monkeypatch.setenv("SECURE3D_NUMBA_CACHE_DIR", str(tmp_path))
    assert km.manifest_path().parent == tmp_path
    monkeypatch.setenv(km.MANIFEST_ENV, str(tmp_path / "x.pickle"))
    assert km.manifest_path() == tmp_path / "x.pickle"
