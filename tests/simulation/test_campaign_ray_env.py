"""Ray actors on a cluster start with the driver's numpy kernels (``campaign_ray.actor_env``).

A real Ray head is started in its own process with an environment *without*
``NPY_DISABLE_CPU_FEATURES`` (as a cluster's nodes are started, apart from the driver), and the
campaign's pool joins it by address: its actors must still run with the driver's setting.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from secure3d._numpy_kernels import NUMPY_ENV
from secure3d.simulation import campaign_ray

RAY = Path(sys.executable).with_name("ray")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def head():
    """A Ray head of one CPU, started without the numpy variable; yields its address. Its temp
    folder is its own (short, for Ray's socket paths), so the file naming the latest cluster
    started on this machine is not the one ``ray.init()`` looks for in other tests."""
    ray_cmd = str(RAY) if RAY.exists() else shutil.which("ray")
    if ray_cmd is None:
        pytest.skip("no ray command")
    port = _free_port()
    folder = tempfile.mkdtemp(prefix="s3dray", dir="/tmp")
    env = {k: v for k, v in os.environ.items() if k != NUMPY_ENV}
    env["RAY_TMPDIR"] = folder
    cmd = [ray_cmd, "start", "--head", "--block"]
    cmd += [f"--port={port}", "--num-cpus=1", "--include-dashboard=false", "--disable-usage-stats"]
    proc = subprocess.Popen(
        cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True
    )
    try:
        yield f"127.0.0.1:{port}"
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
        shutil.rmtree(folder, ignore_errors=True)


def _connect(address: str) -> campaign_ray.RayPool:
    deadline = time.monotonic() + 90
    while True:
        try:
            return campaign_ray.RayPool(1, address=address)
        except Exception:  # the head is still starting
            if time.monotonic() > deadline:
                raise
            time.sleep(1.0)


def test_actors_on_a_cluster_get_the_drivers_numpy_setting(head, monkeypatch):
    """A user's own setting, not the one ``import secure3d`` would make in the actor (which the
    actor would make if the variable did not reach it: Ray's workers import numpy only after
    unpickling the actor's class, which imports secure3d first)."""
    import ray

    monkeypatch.setenv(NUMPY_ENV, "AVX512_SPR")
    assert campaign_ray.actor_env() == {NUMPY_ENV: "AVX512_SPR"}
    pool = _connect(head)
    try:
        got = ray.get(pool._actor(0).numpy_kernels.remote(), timeout=120)
        assert got["env"] == "AVX512_SPR", got
        assert got["mode"] == "native" and "set by the user" in got["reason"], got
        assert "AVX512_SPR" not in got["dispatch"], got
    finally:
        pool.kill(0)
        ray.shutdown()


def test_no_setting_is_invented(monkeypatch):
    monkeypatch.delenv(NUMPY_ENV, raising=False)
    assert campaign_ray.actor_env() == {}
