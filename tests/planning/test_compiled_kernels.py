"""The node kernels' derivatives compiled to C: the same values as CasADi's VM bit for bit, a cache
that other processes find, background compiles, and the VM whenever a library is missing, wrong or
cannot be built."""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from secure3d.errors import ConfigError
from secure3d.planning import NLPCache, compiled_kernels, plan_problem, problem_from_scenario
from secure3d.planning.assembled_derivatives import _kernel_derivatives
from secure3d.planning.compiled_kernels import KernelTag
from secure3d.planning.kernels import node_kernels
from secure3d.world import load_scenario

pytestmark = pytest.mark.skipif(
    compiled_kernels._compiler() is None, reason="no C compiler on this machine"
)


@pytest.fixture
def kernel_cache(tmp_path, monkeypatch):
    """A fresh cache folder and a fresh process state (loaded libraries, queue, compiler)."""
    monkeypatch.setenv("SECURE3D_KERNEL_CACHE_DIR", str(tmp_path / "kernels"))
    monkeypatch.setattr(compiled_kernels, "_STATE", compiled_kernels._State())
    compiled_kernels._compiler.cache_clear()
    yield tmp_path / "kernels"
    compiled_kernels.wait(timeout=120)
    compiled_kernels._compiler.cache_clear()


def _point_mass_kernels(maps_dir):
    problem = problem_from_scenario(load_scenario(maps_dir / "blind_corner.yaml"))
    return node_kernels(problem)


def _values(fn: ca.Function, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    args = [rng.normal(size=fn.sparsity_in(i).shape) for i in range(fn.n_in())]
    return [np.asarray(ca.DM(out).nonzeros()) for out in fn.call(args)]


def test_compiled_derivatives_equal_the_vms_bit_for_bit(maps_dir, kernel_cache, monkeypatch):
    monkeypatch.setenv(compiled_kernels.MODE_ENV, "now")
    kern = _point_mass_kernels(maps_dir)
    for fn, dec in ((kern.obs_view, (0, 1, 3)), (kern.vis, (0, 1)), (kern.dyn, (0, 1, 2, 3, 4, 5))):
        monkeypatch.setenv(compiled_kernels.MODE_ENV, "off")
        jac_vm, hess_vm = _kernel_derivatives(fn, dec, cache := {})
        monkeypatch.setenv(compiled_kernels.MODE_ENV, "now")
        jac_c, hess_c = _kernel_derivatives(fn, dec, cache)
        for vm, c in ((jac_vm, jac_c), (hess_vm, hess_c)):
            assert c is not vm and c.class_name() != vm.class_name(), fn.name()
            for seed in range(5):
                for a, b in zip(_values(vm, seed), _values(c, seed), strict=True):
                    assert np.array_equal(a, b, equal_nan=True), fn.name()
    libs = sorted(p.name for p in kernel_cache.iterdir())
    assert len(libs) == 6 and all(name.endswith("-O1.so") for name in libs), libs
    assert compiled_kernels.status()["loaded"] == 6


@pytest.mark.parametrize(
    ("name", "planner"),
    [
        ("blind_corner.yaml", "secure"),
        ("blind_corner.yaml", "baseline"),
        ("blind_corner_quadrotor.yaml", "secure"),
    ],
)
def test_plans_with_compiled_kernels_equal_the_vms(
    maps_dir, kernel_cache, monkeypatch, name, planner
):
    problem = problem_from_scenario(load_scenario(maps_dir / name))
    plans = {}
    for how in ("off", "now"):
        monkeypatch.setenv(compiled_kernels.MODE_ENV, how)
        plans[how] = plan_problem(problem, planner, cache=NLPCache())
    assert compiled_kernels.status()["loaded"] > 0
    off, now = plans["off"], plans["now"]
    assert off.ok and now.ok
    assert now.iterations == off.iterations
    assert now.final_time == off.final_time
    for field in ("times", "states", "controls"):
        assert np.array_equal(getattr(now, field), getattr(off, field)), field


def test_background_compiles_quickly_then_well_and_cleans_up(maps_dir, kernel_cache, monkeypatch):
    monkeypatch.setenv(compiled_kernels.MODE_ENV, "background")
    kern = _point_mass_kernels(maps_dir)
    jac, hess = _kernel_derivatives(kern.vis, (0, 1), cache := {})
    assert jac.class_name() == "SXFunction" and hess.class_name() == "SXFunction"
    assert compiled_kernels.status()["queued"] >= 1  # two kernels at two levels, some maybe done
    assert compiled_kernels.wait(timeout=300)
    names = sorted(p.name for p in kernel_cache.iterdir())
    assert len(names) == 4 and sum(n.endswith("-O0.so") for n in names) == 2, names
    assert not [n for n in names if n.endswith((".c", ".lock", ".tmp"))], names
    jac2, hess2 = _kernel_derivatives(kern.vis, (0, 1), cache)
    assert jac2.class_name() != "SXFunction" and hess2.class_name() != "SXFunction"
    assert compiled_kernels.status() == {"loaded": 2, "queued": 0, "failed": 0, "rejected": 0}


def test_a_library_with_other_values_is_not_used(maps_dir, kernel_cache, monkeypatch, caplog):
    monkeypatch.setenv(compiled_kernels.MODE_ENV, "off")
    kern = _point_mass_kernels(maps_dir)
    _, hess = _kernel_derivatives(kern.vis, (0, 1), {})
    monkeypatch.setenv(compiled_kernels.MODE_ENV, "now")
    # the library of another function with the same name and shapes, under vis's file name
    x = [ca.SX.sym(f"in{i}", hess.sparsity_in(i)) for i in range(hess.n_in())]
    wrong = ca.Function(hess.name(), x, [1.5 * hess(*x)])
    tag = KernelTag("not-the-kernel", (0,), "hess")
    compiled_kernels.best(wrong, tag)
    stem = KernelTag.of(kern.vis, (0, 1), "hess").digest(compiled_kernels._compiler()[1])
    (kernel_cache / f"{tag.digest(compiled_kernels._compiler()[1])}-O1.so").rename(
        kernel_cache / f"{stem}-O1.so"
    )
    monkeypatch.setattr(compiled_kernels, "_STATE", compiled_kernels._State())
    with caplog.at_level(logging.WARNING):
        _, used = _kernel_derivatives(kern.vis, (0, 1), {})
    assert used.class_name() == "SXFunction"
    assert compiled_kernels.status()["rejected"] == 1
    assert "differs from CasADi's VM" in caplog.text


def test_a_failing_compiler_leaves_the_vm(maps_dir, kernel_cache, tmp_path, monkeypatch, caplog):
    fake = tmp_path / "badcc"
    fake.write_text(
        '#!/bin/sh\nif [ "$1" = --version ]; then echo "badcc 1.0"; exit 0; fi\n'
        'echo "badcc: cannot compile" >&2; exit 1\n'
    )
    fake.chmod(0o755)
    monkeypatch.setenv("CC", str(fake))
    compiled_kernels._compiler.cache_clear()
    monkeypatch.setenv(compiled_kernels.MODE_ENV, "now")
    kern = _point_mass_kernels(maps_dir)
    with caplog.at_level(logging.WARNING):
        jac, hess = _kernel_derivatives(kern.vis, (0, 1), {})
    assert jac.class_name() == "SXFunction" and hess.class_name() == "SXFunction"
    assert compiled_kernels.status()["failed"] == 2
    assert "badcc: cannot compile" in caplog.text
    assert not [p for p in kernel_cache.iterdir() if p.suffix in (".so", ".lock", ".tmp")]


def test_no_compiler_or_mode_off_means_the_vm(maps_dir, kernel_cache, monkeypatch):
    kern = _point_mass_kernels(maps_dir)
    monkeypatch.setenv("CC", "/nonexistent/cc")
    compiled_kernels._compiler.cache_clear()
    monkeypatch.setenv(compiled_kernels.MODE_ENV, "now")
    assert _kernel_derivatives(kern.vis, (0, 1), {})[1].class_name() == "SXFunction"
    monkeypatch.delenv("CC")
    compiled_kernels._compiler.cache_clear()
    monkeypatch.setenv(compiled_kernels.MODE_ENV, "off")
    assert _kernel_derivatives(kern.vis, (0, 1), {})[1].class_name() == "SXFunction"
    assert not kernel_cache.exists()


def test_a_bad_mode_is_named(monkeypatch):
    monkeypatch.setenv(compiled_kernels.MODE_ENV, "sometimes")
    with pytest.raises(
        ConfigError, match="SECURE3D_KERNEL_COMPILE.*auto, background, now, off.*sometimes"
    ):
        compiled_kernels.mode()


def test_a_held_lock_is_respected_and_a_stale_one_replaced(kernel_cache):
    kernel_cache.mkdir(parents=True)
    lock = kernel_cache / "x-O0.lock"
    lock.write_text("123")
    assert not compiled_kernels._take_lock(lock)
    old = time.time() - compiled_kernels.STALE_LOCK - 10
    os.utime(lock, (old, old))
    assert compiled_kernels._take_lock(lock)
    assert lock.read_text() == str(os.getpid())


def test_a_kernels_tag_is_the_same_in_another_process(maps_dir):
    """The cache is found by name: the digest of a kernel must not depend on the process."""
    code = (
        "import json, sys\n"
        "from secure3d.planning import problem_from_scenario\n"
        "from secure3d.planning.compiled_kernels import KernelTag\n"
        "from secure3d.planning.kernels import node_kernels\n"
        "from secure3d.world import load_scenario\n"
        f"k = node_kernels(problem_from_scenario(load_scenario({str(maps_dir / 'blind_corner.yaml')!r})))\n"
        "print(json.dumps([KernelTag.of(k.obs_view, (0, 1, 3), 'hess').kernel_digest,"
        " KernelTag.of(k.dyn, (0,), 'jac').kernel_digest]))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    there = json.loads(out.stdout.strip().splitlines()[-1])
    kern = _point_mass_kernels(maps_dir)
    here = [
        KernelTag.of(kern.obs_view, (0, 1, 3), "hess").kernel_digest,
        KernelTag.of(kern.dyn, (0,), "jac").kernel_digest,
    ]
    assert here == there
    assert here[0] != here[1]


def test_the_cache_root_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.delenv("SECURE3D_KERNEL_CACHE_DIR", raising=False)
    monkeypatch.setenv("SECURE3D_CACHE_DIR", str(tmp_path / "shared"))
    assert compiled_kernels.cache_root() == tmp_path / "shared" / "kernels"
    monkeypatch.delenv("SECURE3D_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert compiled_kernels.cache_root() == Path(tmp_path / "xdg" / "secure3d" / "kernels")


def test_a_forked_child_starts_with_its_own_state(kernel_cache):
    """A child forked from a process with a background thread must not wait on the parent's."""
    st = compiled_kernels._state()
    assert compiled_kernels._state() is st
    st.pid = -1  # as the child of a fork sees its parent's state
    fresh = compiled_kernels._state()
    assert fresh is not st and fresh.pid == os.getpid() and fresh.worker is None


def test_an_unwritable_cache_leaves_the_vm_and_warns_once(maps_dir, tmp_path, monkeypatch, caplog):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("SECURE3D_KERNEL_CACHE_DIR", str(blocker / "kernels"))
    monkeypatch.setattr(compiled_kernels, "_STATE", compiled_kernels._State())
    kern = _point_mass_kernels(maps_dir)
    for how in ("background", "now"):
        monkeypatch.setenv(compiled_kernels.MODE_ENV, how)
        with caplog.at_level(logging.WARNING):
            for _ in range(3):
                assert _kernel_derivatives(kern.vis, (0, 1), {})[1].class_name() == "SXFunction"
    assert caplog.text.count("cannot compile kernel") == 2  # the Jacobian's and the Hessian's


def test_auto_compiles_only_what_an_earlier_process_met(maps_dir, kernel_cache, monkeypatch):
    """A one-off run is not slowed by compiling beside it; the second process to meet a kernel
    compiles it."""
    monkeypatch.setenv(compiled_kernels.MODE_ENV, "auto")
    kern = _point_mass_kernels(maps_dir)
    jac, hess = _kernel_derivatives(kern.vis, (0, 1), {})
    assert hess.class_name() == "SXFunction" and compiled_kernels.status()["queued"] == 0
    marks = sorted(kernel_cache.glob("*.seen"))
    assert len(marks) == 2 and marks[0].read_text() == str(os.getpid())
    assert not list(kernel_cache.glob("*.so"))
    for mark in marks:  # as if an earlier process had met them
        mark.write_text("1")
    monkeypatch.setattr(compiled_kernels, "_STATE", compiled_kernels._State())
    _kernel_derivatives(kern.vis, (0, 1), {})
    assert compiled_kernels.status()["queued"] >= 1
    assert compiled_kernels.wait(timeout=300)
    assert len(list(kernel_cache.glob("*.so"))) == 4  # two kernels at two levels


def test_the_default_mode_yields_to_the_environment(monkeypatch):
    monkeypatch.delenv(compiled_kernels.MODE_ENV, raising=False)
    assert compiled_kernels.mode() == "auto"
    with compiled_kernels.default_mode("background"):
        assert compiled_kernels.mode() == "background"
        monkeypatch.setenv(compiled_kernels.MODE_ENV, "off")
        assert compiled_kernels.mode() == "off"
    monkeypatch.delenv(compiled_kernels.MODE_ENV)
    assert compiled_kernels.mode() == "auto"
    with pytest.raises(ConfigError, match="compile mode.*auto, background, now, off.*soon"):
        with compiled_kernels.default_mode("soon"):
            pass


def test_bad_arguments_are_named(maps_dir):
    kern = _point_mass_kernels(maps_dir)
    with pytest.raises(ConfigError, match="dec must be input indices of vis.*got \\(0, 9\\)"):
        KernelTag.of(kern.vis, (0, 9), "hess")
    with pytest.raises(ConfigError, match="kernel must be a casadi.Function"):
        KernelTag.of("vis", (0,), "hess")
    with pytest.raises(ConfigError, match="expected a casadi.Function and a KernelTag"):
        compiled_kernels.best(kern.vis, "tag")


def test_a_tags_role_changes_without_a_second_serialisation(maps_dir):
    kern = _point_mass_kernels(maps_dir)
    jac = KernelTag.of(kern.vis, (0, 1), "jac")
    hess = jac.with_role("hess")
    assert hess == KernelTag.of(kern.vis, (0, 1), "hess")
    assert hess != jac and hess.digest("cc 1") != jac.digest("cc 1")


def _fake_library(folder: Path, stem: str, level: str, size: int, age_days: float) -> Path:
    path = folder / f"{stem}{level}.so"
    path.write_bytes(b"\0" * size)
    t = time.time() - age_days * 86400.0
    os.utime(path, (t, t))
    return path


def test_prune_drops_the_least_recently_used_libraries_beyond_the_cap(kernel_cache, monkeypatch):
    kernel_cache.mkdir(parents=True)
    stems = [f"{i:024x}" for i in range(5)]
    libs = [
        _fake_library(kernel_cache, s, "-O1", 1000, age_days=10 - i) for i, s in enumerate(stems)
    ]
    compiled_kernels._state().loaded[stems[0]] = (1, None)  # the oldest is loaded here: kept
    old_mark, fresh_mark, kept_mark = (
        kernel_cache / f"{s}.seen" for s in ("f" * 24, "e" * 24, stems[4])
    )
    for mark, age in ((old_mark, 40.0), (fresh_mark, 1.0), (kept_mark, 40.0)):
        mark.write_text("1")
        os.utime(mark, (time.time() - age * 86400.0,) * 2)
    removed = compiled_kernels.prune(cap_bytes=3000, spare=stems[1])
    assert sorted(removed) == sorted([libs[2], libs[3], old_mark]), removed
    assert all(p.exists() for p in (libs[0], libs[1], libs[4], fresh_mark, kept_mark))
    monkeypatch.setenv(compiled_kernels.CACHE_MB_ENV, "0.004")
    assert compiled_kernels.prune() == [] and compiled_kernels.cache_cap_bytes() == 4000.0
    with pytest.raises(ConfigError, match="cap_bytes must be a number >= 0, got -1"):
        compiled_kernels.prune(cap_bytes=-1)
    monkeypatch.setenv(compiled_kernels.CACHE_MB_ENV, "lots")
    with pytest.raises(ConfigError, match="SECURE3D_KERNEL_CACHE_MB.*positive.*'lots'"):
        compiled_kernels.prune()


def test_a_compile_keeps_the_cache_within_its_cap_and_loads_mark_use(
    maps_dir, kernel_cache, monkeypatch
):
    kernel_cache.mkdir(parents=True)
    stale = _fake_library(kernel_cache, "0" * 24, "-O1", 200_000, age_days=30)
    monkeypatch.setenv(compiled_kernels.CACHE_MB_ENV, "0.15")  # below the stale one alone
    monkeypatch.setenv(compiled_kernels.MODE_ENV, "now")
    kern = _point_mass_kernels(maps_dir)
    jac, _ = _kernel_derivatives(kern.vis, (0, 1), {})
    assert jac.class_name() != "SXFunction" and not stale.exists()
    libs = sorted(kernel_cache.glob("*.so"))
    assert len(libs) == 2, libs  # the Jacobian's and the Hessian's: each loaded, so kept
    for lib in libs:
        os.utime(lib, (1.0e9, 1.0e9))
    monkeypatch.setattr(compiled_kernels, "_STATE", compiled_kernels._State())
    _kernel_derivatives(kern.vis, (0, 1), {})
    assert all(lib.stat().st_mtime > time.time() - 60 for lib in libs), "a load marks its use"
