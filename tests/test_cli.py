"""The ``secure3d`` command line: ``show`` prints a summary or JSON, errors are one line, exit 2."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from secure3d.cli import COMMANDS, main
from secure3d.world import load_scenario, scenario_from_dict, scenario_to_dict

REPO = Path(__file__).resolve().parents[1]
MAPS = REPO / "maps"


@pytest.fixture
def bad_file(tmp_path: Path) -> Path:
    data = yaml.safe_load((MAPS / "blind_corner.yaml").read_text())
    data["start"]["position"] = [1.0, float("nan"), 1.25]
    path = tmp_path / "nan_start.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_show_prints_the_summary(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["show", str(MAPS / "warehouse.yaml")]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert out.rstrip("\n") == load_scenario(MAPS / "warehouse.yaml").summary()
    assert "PHANTOM" in out and "SHIFTED" in out


def test_show_json_is_the_full_scenario(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["show", "--json", str(MAPS / "forest.yaml")]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["name"] == "forest" and len(data["world"]["meshes"]) == 20
    rebuilt = scenario_from_dict(data, MAPS)
    assert scenario_to_dict(rebuilt, MAPS) == data


def test_show_error_is_one_line_exit_2(bad_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["show", str(bad_file)]) == 2
    out, err = capsys.readouterr()
    assert out == ""
    assert err.count("\n") == 1, err
    assert err.startswith(f"secure3d: error: {bad_file}: start.position: must be finite"), err


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["show", "no/such/file.yaml"], "no/such/file.yaml: no such file"),
        (["show"], "required: scenario"),
        (["fly"], "invalid choice: 'fly'"),
        ([], "required: COMMAND"),
        (["show", "--bogus", "x.yaml"], "unrecognized arguments: --bogus"),
    ],
)
def test_usage_errors_are_one_line_exit_2(
    argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("secure3d: error: "), err
    assert needle in err, err


def test_help_and_version_exit_0(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in COMMANDS:
        assert command.name in out
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.startswith("secure3d ")


def test_version_names_the_numpy_kernels() -> None:
    """A fresh ``secure3d --version`` without the Makefile's variable: numpy held by the import."""
    env = {k: v for k, v in os.environ.items() if k != "NPY_DISABLE_CPU_FEATURES"}
    env.pop("SECURE3D_NUMPY_KERNELS", None)
    env["PYTHONPATH"] = str(REPO)
    out = subprocess.run(
        [sys.executable, "-m", "secure3d", "--version"], capture_output=True, text=True, env=env
    )
    assert out.returncode == 0, out.stderr
    first, second = out.stdout.strip().splitlines()
    assert first.startswith("secure3d ")
    assert "kernels portable (" in second and "X86_V4" not in second.split("(")[1].split(")")[0]
    assert "NPY_DISABLE_CPU_FEATURES=X86_V4 AVX512_ICL AVX512_SPR" in second
    native = subprocess.run(
        [sys.executable, "-m", "secure3d", "--version"],
        capture_output=True,
        text=True,
        env={**env, "SECURE3D_NUMPY_KERNELS": "native"},
    )
    assert "kernels native (" in native.stdout and "SECURE3D_NUMPY_KERNELS=native" in native.stdout


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run(
        [sys.executable, "-m", "secure3d", *args],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=env,
        timeout=60,
    )


def test_subprocess_success_and_failure(bad_file: Path) -> None:
    ok = _run("show", "maps/blind_corner.yaml")
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.startswith("Scenario 'blind_corner'") and "HIDDEN" in ok.stdout
    bad = _run("show", str(bad_file))
    assert bad.returncode == 2
    assert bad.stdout == ""
    assert "Traceback" not in bad.stderr
    assert bad.stderr.count("\n") == 1 and "start.position" in bad.stderr, bad.stderr


def test_show_does_not_import_heavy_modules() -> None:
    # casadi is allowed: validating vehicle limits builds the dynamics model, which uses it.
    code = (
        "import sys; from secure3d.cli import main; main(['show', 'maps/blind_corner.yaml']);"
        "print(sorted(m for m in ('open3d', 'rerun', 'fcl', 'matplotlib') if m in sys.modules))"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, env=env, timeout=60
    )
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "[]", "show must stay light"


def test_a_reader_that_closes_the_pipe_gets_no_traceback(maps_dir):
    """`secure3d show ... | head` used to end in a BrokenPipeError traceback."""
    import subprocess
    import sys

    child = subprocess.Popen(
        [sys.executable, "-m", "secure3d", "show", str(maps_dir / "blind_corner.yaml")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    child.stdout.close()  # the reader is gone before the first line
    err = child.stderr.read()
    child.wait(timeout=120)
    assert "Traceback" not in err, err
    assert err.strip().count("\n") == 0 and "broken pipe" in err, err
    assert child.returncode == 1


def test_the_cli_loads_without_casadi_or_open3d():
    """``secure3d show`` and ``--help`` must not pay for the solver or the ray caster: every
    runner imports what it needs inside its body."""
    code = (
        "import sys, secure3d.cli; "
        "print(sorted(m for m in ('casadi', 'open3d', 'numba') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
