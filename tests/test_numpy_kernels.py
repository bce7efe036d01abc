"""``import secure3d`` holds numpy to its AVX2 kernels (``secure3d._numpy_kernels``).

Every case runs in a fresh interpreter, because numpy picks its kernels once, at its import, and
the test process imported numpy long ago (under ``make test`` with ``NPY_DISABLE_CPU_FEATURES``
already set by the Makefile, which each case here removes from the child's environment).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
ABOVE_AVX2 = {"X86_V4", "AVX512_ICL", "AVX512_SPR", "AVX512F", "AVX512_SKX"}


def _child(code: str, **env: str) -> subprocess.CompletedProcess:
    drop = ("NPY_DISABLE_CPU_FEATURES", "SECURE3D_NUMPY_KERNELS")
    clean = {k: v for k, v in os.environ.items() if k not in drop}
    clean.update(env)
    return subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=clean, timeout=600
    )


_REPORT = (
    "import json, os, sys\n"
    "{first}\n"
    "k = secure3d.numpy_kernels()\n"
    "k['env'] = os.environ.get('NPY_DISABLE_CPU_FEATURES')\n"
    "print(json.dumps(k))\n"
)


def _report(first: str, **env: str) -> dict:
    out = _child(_REPORT.format(first=first), **env)
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout)


def test_import_secure3d_first_holds_numpy_to_avx2():
    k = _report("import secure3d\nimport numpy")
    assert k["mode"] == "portable", k
    assert k["env"] == "X86_V4 AVX512_ICL AVX512_SPR"
    assert not ABOVE_AVX2 & set(k["dispatch"]), k["dispatch"]  # on any CPU


def test_numpy_imported_first_is_left_alone_and_says_so():
    k = _report("import numpy\nimport secure3d")
    assert k["mode"] == "native"
    assert "numpy was imported before secure3d" in k["reason"]
    assert k["env"] is None  # nothing set that would reach the processes it starts either


def test_native_and_the_users_own_setting_are_kept():
    k = _report("import secure3d", SECURE3D_NUMPY_KERNELS="native")
    assert (k["mode"], k["env"]) == ("native", None)
    k = _report("import secure3d", NPY_DISABLE_CPU_FEATURES="AVX512_SPR")
    assert k["mode"] == "native" and "set by the user" in k["reason"]
    assert k["env"] == "AVX512_SPR"


def test_a_bad_choice_is_a_one_line_error_naming_the_variable():
    out = _child("import secure3d", SECURE3D_NUMPY_KERNELS="fastest")
    assert out.returncode != 0
    last = out.stderr.strip().splitlines()[-1]
    assert "ConfigError: SECURE3D_NUMPY_KERNELS: must be one of portable, native" in last
    assert "'fastest'" in last


def test_the_numpy_release_is_read_without_importing_numpy():
    out = _child(
        "import sys\nfrom secure3d._numpy_kernels import _numpy_release\n"
        "import importlib.metadata as m\n"
        "r = _numpy_release()\n"
        "assert 'numpy' not in sys.modules\n"
        "print(r == tuple(int(p) for p in m.version('numpy').split('.')[:2]))"
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "True"


@pytest.mark.slow
def test_the_pinned_planar_plan_without_the_makefiles_variable():
    """The planar plan that numpy's AVX-512 kernels moved past the golden tolerance on an AVX-512
    CPU (2e-6 relative), planned by a process that imports secure3d first and has no
    ``NPY_DISABLE_CPU_FEATURES``: what a user's script or ``secure3d plan`` gets."""
    code = (
        "import secure3d, json, sys\n"
        f"sys.path.insert(0, {str(HERE)!r})\n"
        "import test_golden_outputs as g\n"
        "print(json.dumps(g.plan_snapshot(('planar_secure',))))\n"
    )
    out = _child(code)
    assert out.returncode == 0, out.stderr[-3000:]
    sys.path.insert(0, str(HERE))
    try:
        import test_golden_outputs as golden_module
    finally:
        sys.path.remove(str(HERE))
    golden = json.loads(golden_module.GOLDEN.read_text())["plans"]["planar_secure"]
    found = golden_module.difference(json.loads(out.stdout)["planar_secure"], golden, "planar")
    assert found is None, found
