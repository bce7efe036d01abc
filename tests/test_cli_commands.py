"""The ``plan``, ``simulate``, ``campaign``, ``bench``, ``reactive`` and ``demo`` subcommands.

Every command runs through ``main([...])`` on a tiny scenario (a 6 m room with one wall, 12 nodes),
so the whole file stays fast. Checked: exit codes, what is printed (against an independent
reading of the scenario or of the files written), files created with no ``.part`` leftovers, and
one-line errors (exit 2) for missing scenarios and bad options.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from secure3d import cli
from secure3d.cli import COMMANDS, main
from secure3d.world import load_scenario

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"

#: A 6 m x 3 m room with one wall to go around (tests/data/tiny_room.yaml).
TINY = (Path(__file__).resolve().parents[0] / "data" / "tiny_room.yaml").read_text()

# The server claims a pallet around the goal: the planner must refuse at once (INVALID_INPUT).
PHANTOM_AT_GOAL = """\
  attacks:
    - kind: phantom
      box: {name: pallet, lo: [4.9, 0.5, 0.0], hi: [5.5, 1.1, 2.0]}
"""


@pytest.fixture(scope="module")
def goal_blocked(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("scenarios") / "goal_blocked.yaml"
    path.write_text(
        TINY.replace("server_map: {resolution: 0.1}\n", "server_map:\n" + PHANTOM_AT_GOAL)
    )
    return path


def _no_partials(folder: Path) -> None:
    leftovers = sorted(p.name for p in folder.rglob("*") if p.name.endswith(".part"))
    assert leftovers == [], f"temporary files left behind: {leftovers}"


def _one_line_error(capsys: pytest.CaptureFixture[str], needle: str) -> None:
    out, err = capsys.readouterr()
    assert err.count("\n") == 1 and err.startswith("secure3d: error: "), err
    assert needle in err, err
    assert "Traceback" not in err


# ---- plan --------------------------------------------------------------------------------------


def test_plan_json_describes_dynamically_consistent_plans(
    tiny: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["plan", str(tiny), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    scenario = load_scenario(tiny)
    assert [d["planner"] for d in data] == ["secure", "baseline"]
    for d in data:
        pos, t = np.array(d["positions"]), np.array(d["times"])
        assert d["status"] == "success" and d["ok"]
        assert len(pos) == 12, "the scenario asks for 12 nodes"
        np.testing.assert_allclose(d["final_time"], t[-1], atol=1e-12)
        np.testing.assert_allclose(pos[0], scenario.start.position, atol=1e-6, err_msg="start")
        np.testing.assert_allclose(pos[-1], scenario.goal.position, atol=1e-3, err_msg="goal")
        # Independent of the planner's own bookkeeping: the path must go around the wall
        # (x in [2.8, 3.2], y < 1.8) with the body radius to spare.
        at_wall = np.abs(pos[:, 0] - 3.0) < 0.4
        assert np.all(pos[at_wall, 1] > 1.8), d["planner"]
    secure, baseline = data
    assert secure["certified"] is True and secure["min_margin"] >= 0
    assert baseline["certified"] is None
    assert secure["final_time"] >= baseline["final_time"] - 1e-6, "security cannot be free"


def test_plan_table_and_png(tiny: Path, tmp_path: Path, capsys) -> None:
    png = tmp_path / "figs" / "plans.png"
    assert (
        main(["plan", str(tiny), "--planner", "baseline", "--nodes", "10", "--png", str(png)]) == 0
    )
    out = capsys.readouterr().out
    lines = out.splitlines()
    header = lines[1].split()
    for column in ("planner", "status", "final", "build", "solve", "iterations", "certified"):
        assert column in header, out
    rows = [line.split() for line in lines[3:] if line.startswith(("secure", "baseline"))]
    assert [r[0] for r in rows] == ["baseline"] and rows[0][1] == "success", out
    assert png.read_bytes().startswith(PNG_MAGIC)
    assert f"wrote {png}" in out
    _no_partials(tmp_path)


def test_plan_failure_exits_1_with_the_reason(goal_blocked: Path, capsys) -> None:
    assert main(["plan", str(goal_blocked), "--planner", "baseline"]) == 1
    out, err = capsys.readouterr()
    assert err == ""
    assert "invalid_input" in out and "goal" in out and "inside a known obstacle" in out, out


# ---- simulate ----------------------------------------------------------------------------------


def test_simulate_writes_recording_and_figures(tiny: Path, tmp_path: Path, capsys) -> None:
    out_dir = tmp_path / "sim"
    rrd, png, speed = out_dir / "run.rrd", out_dir / "top.png", out_dir / "speed.png"
    argv = ["simulate", str(tiny), "--planner", "baseline", "--seed", "3", "--events"]
    argv += ["--rrd", str(rrd), "--png", str(png), "--speed-png", str(speed)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert out.startswith("tiny_room / baseline: REACHED GOAL"), out
    assert "goal reached" in out, "--events lists the run's events"
    for path in (png, speed):
        assert path.read_bytes().startswith(PNG_MAGIC), path
    assert rrd.stat().st_size > 1000
    assert sorted(p.name for p in out_dir.iterdir()) == ["run.rrd", "speed.png", "top.png"]
    _no_partials(tmp_path)


def test_simulate_rejects_a_negative_replan_latency(tiny: Path, capsys) -> None:
    assert main(["simulate", str(tiny), "--planner", "baseline", "--replan-latency", "-1"]) == 2
    err = capsys.readouterr().err
    assert "replan_latency" in err and len(err.strip().splitlines()) == 1, err


@pytest.mark.slow
def test_simulate_both_names_one_recording_per_planner(tiny: Path, tmp_path: Path, capsys) -> None:
    rrd = tmp_path / "run.rrd"
    assert main(["simulate", str(tiny), "--rrd", str(rrd)]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "run_secure.rrd").is_file() and (tmp_path / "run_baseline.rrd").is_file()
    assert not rrd.exists()
    assert "planner" in out and "price of security" in out, out


# ---- campaign ----------------------------------------------------------------------------------


def test_campaign_writes_csv_and_summary(tiny: Path, tmp_path: Path, capsys) -> None:
    out_dir = tmp_path / "campaign"
    argv = ["campaign", str(tiny), "-n", "2", "--planners", "baseline", "--workers", "1"]
    argv += ["--out", str(out_dir), "--no-progress", "--seed", "5"]
    assert main(argv) == 0
    out, err = capsys.readouterr()
    with open(out_dir / "campaign.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["variant"], r["seed"], r["planner"]) for r in rows] == [
        ("0", "5", "baseline"),
        ("1", "6", "baseline"),
    ]
    assert [r["scenario"] for r in rows] == ["tiny_room_hidden_000", "tiny_room_hidden_001"]
    summary = (out_dir / "summary.md").read_text()
    assert summary.rstrip() in out, "the summary is printed"
    collisions = sum(r["collided"] == "1" for r in rows)
    assert f"| baseline | 2 | {collisions} |" in summary, summary
    assert sorted(p.name for p in out_dir.iterdir()) == ["campaign.csv", "runs.csv", "summary.md"]
    assert err == "", "no progress bar with --no-progress"


def test_campaign_flies_and_records_the_slot_pick(tiny: Path, tmp_path: Path, capsys) -> None:
    out_dir = tmp_path / "campaign"
    argv = ["campaign", str(tiny), "-n", "1", "--planners", "secure", "--workers", "1"]
    argv += ["--out", str(out_dir), "--no-progress", "--slot-pick", "directions"]
    assert main(argv) == 0
    header = (out_dir / "runs.csv").read_text().splitlines()[0]
    assert json.loads(header.removeprefix("# secure3d campaign "))["options"] == {
        "slot_pick": "directions"
    }
    with open(out_dir / "campaign.csv", newline="") as fh:
        (row,) = list(csv.DictReader(fh))
    assert row["error"] == "" and row["collided"] == "0"
    assert main(["plan", str(tiny), "--slot-pick", "farthest"]) == 2
    assert "--slot-pick" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["campaign", "{tiny}", "-n", "0", "--out", "{tmp}"], "n: must be a positive integer"),
        (["campaign", "{tiny}", "-n", "1", "--planners", "secure,fast"], "--planners"),
        (["campaign", "{tiny}", "-n", "1", "--workers", "0", "--out", "{tmp}"], "workers"),
        (["campaign", "{tiny}", "-n", "1", "--nodes", "2", "--out", "{tmp}"], "nodes"),
        (["campaign", "{tiny}"], "required: -n"),
        (["campaign", "no/such.yaml", "-n", "1", "--out", "{tmp}"], "no/such.yaml: no such file"),
    ],
)
def test_campaign_errors_are_one_line(
    argv: list[str], needle: str, tiny: Path, tmp_path: Path, capsys
) -> None:
    argv = [a.format(tiny=tiny, tmp=tmp_path / "out") for a in argv]
    assert main(argv) == 2
    _one_line_error(capsys, needle)
    assert not (tmp_path / "out" / "campaign.csv").exists()


# ---- errors shared by the commands -------------------------------------------------------------


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["plan", "no/such/file.yaml"], "no/such/file.yaml: no such file"),
        (["simulate", "no/such/file.yaml"], "no/such/file.yaml: no such file"),
        (["demo", "--scenario", "no/such/file.yaml"], "no/such/file.yaml: no such file"),
        (["plan", "{tiny}", "--nodes", "3"], "nodes"),
        (["plan", "{tiny}", "--solver", "snopt"], "invalid choice: 'snopt'"),
        (["plan", "{tiny}", "--planner", "fast"], "invalid choice: 'fast'"),
        (["plan", "{tiny}", "--nodes", "many"], "invalid int value: 'many'"),
        (["simulate", "{tiny}", "--seed", "-1"], "--seed: must be a non-negative integer"),
        (["bench", "gpu"], "invalid choice: 'gpu'"),
        (["reactive", "refit"], "invalid choice: 'refit'"),
    ],
)
def test_bad_input_is_one_line_exit_2(argv: list[str], needle: str, tiny: Path, capsys) -> None:
    assert main([a.format(tiny=tiny) for a in argv]) == 2
    _one_line_error(capsys, needle)


def test_output_folder_that_cannot_be_made_is_one_line(tiny: Path, tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["plan", str(tiny), "--png", str(blocker / "sub" / "p.png")]) == 2
    _one_line_error(capsys, "output folder")


@pytest.mark.parametrize("command", [c.name for c in COMMANDS])
def test_every_command_has_help(command: str, capsys) -> None:
    assert main([command, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: secure3d {command}"), out
    if command == "campaign":  # every family, its description as written (a % in it too)
        from secure3d.world.family_registry import FAMILIES

        flat = " ".join(out.split())
        for f in FAMILIES.values():
            assert f"{f.name}: {' '.join(f.description.split())}" in flat, f.name


# ---- bench and reactive: thin wrappers around the repository's scripts -------------------------

FAKE_SCRIPT = """\
import sys

print("ran", __file__.rsplit("/", 1)[-1], sys.argv[1:])
sys.exit(3)
"""


@pytest.mark.parametrize(
    ("argv", "script"),
    [
        (["bench", "mapping", "--repeat", "1"], "bench_mapping.py"),
        (["bench", "planner", "--quick"], "bench_planner.py"),
        (["bench", "closed_loop", "--reps", "1"], "bench_closed_loop.py"),
        (["reactive", "fit", "--family", "point_mass/braking"], "fit_reactive_sets.py"),
    ],
)
def test_scripts_get_the_extra_arguments_and_give_their_status(
    argv: list[str], script: str, tmp_path: Path, capfd
) -> None:
    (tmp_path / script).write_text(FAKE_SCRIPT)
    assert main(argv, scripts=tmp_path) == 3
    assert capfd.readouterr().out.strip() == f"ran {script} {argv[2:]}"


def test_missing_script_is_one_line(tmp_path: Path, capsys) -> None:
    assert main(["bench", "planner"], scripts=tmp_path) == 2
    _one_line_error(capsys, "bench_planner.py not found")


def test_reactive_fit_passes_help_through_to_the_real_script(capfd) -> None:
    assert main(["reactive", "fit", "--help"]) == 0
    out = capfd.readouterr().out
    assert "--n-samples" in out and "--family" in out, out


def test_bench_campaign_is_a_campaign_on_the_blind_corner(monkeypatch) -> None:
    seen: list[list[str]] = []
    real_main = cli.main

    def spy(argv: list[str]) -> int:
        seen.append(list(argv))
        return 0 if argv[0] == "campaign" else real_main(argv)

    monkeypatch.setattr(cli, "main", spy)
    assert real_main(["bench", "campaign", "-n", "3", "--workers", "2"]) == 0
    (argv,) = seen
    assert argv[0] == "campaign" and Path(argv[1]).name == "blind_corner.yaml"
    # The user's options come last, so they override the defaults.
    assert argv[-4:] == ["-n", "3", "--workers", "2"]


# ---- demo --------------------------------------------------------------------------------------


def test_demo_flies_both_planners_and_writes_everything(tiny: Path, tmp_path: Path, capsys) -> None:
    out_dir = tmp_path / "demo"
    assert main(["demo", "--quick", "--scenario", str(tiny), "--out", str(out_dir)]) == 0
    out = capsys.readouterr().out
    expected = {
        "tiny_room_secure.rrd",
        "tiny_room_baseline.rrd",
        "tiny_room_top_down.png",
        "tiny_room_speed.png",
    }
    assert {p.name for p in out_dir.iterdir()} == expected
    for name in expected:
        assert (out_dir / name).stat().st_size > 1000, name
    table = out[out.index("planner  ") :].splitlines()
    assert table[2].startswith("secure") and table[3].startswith("baseline"), out
    assert "paper" not in out, "the paper's numbers are quoted for the blind corner only"
    _no_partials(tmp_path)


def test_demo_scenario_is_found_from_any_folder(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    path = cli._bundled_scenario("blind_corner")
    assert path.is_absolute() and load_scenario(path).name == "blind_corner"


def test_demo_without_its_scenario_is_one_line(tmp_path: Path, monkeypatch, capsys) -> None:
    import secure3d.world.bundled as bundled

    monkeypatch.setattr(bundled, "bundled_dir", lambda: tmp_path)
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--out", str(tmp_path / "out")]) == 2
    _one_line_error(capsys, "blind_corner: no such file, and no shipped scenario of that name")


def test_interrupt_exits_130_with_one_line(tiny: Path, monkeypatch, capsys) -> None:
    def interrupted(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    import secure3d.planning

    monkeypatch.setattr(secure3d.planning, "plan", interrupted)
    assert main(["plan", str(tiny)]) == 130
    _one_line_error(capsys, "interrupted")


def test_bench_mapping_with_a_missing_data_folder_is_one_line(tmp_path):
    """It used to end in a FileNotFoundError traceback."""
    import subprocess
    import sys

    run = subprocess.run(
        [sys.executable, "-m", "secure3d", "bench", "mapping", "--data", str(tmp_path / "none")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 2, run.stderr
    assert "Traceback" not in run.stderr and "no scan.dat.bz2 or geb079.bt" in run.stderr


def test_simulate_json_is_the_runs_as_data(maps_dir, capsys):
    import json

    from secure3d.cli import main

    code = main(
        [
            "simulate",
            str(maps_dir / "blind_corner.yaml"),
            "--planner",
            "secure",
            "--json",
            "--nodes",
            "20",
        ]
    )
    assert code == 0
    runs = json.loads(capsys.readouterr().out)
    assert [r["planner"] for r in runs] == ["secure"]
    run = runs[0]
    assert run["outcome"] in ("reached goal", "collided", "did not arrive", "no plan")
    assert run["collided"] is False and run["plans"] and run["plans"][0]["certificate"]["ok"]
    assert run["events"] and {"time", "kind", "detail"} <= set(run["events"][0])


def test_simulate_refuses_an_output_folder_before_it_flies(maps_dir, tmp_path, capsys):
    """`--png out/` used to fail with a traceback after both flights."""
    from secure3d.cli import main

    code = main(["simulate", str(maps_dir / "blind_corner.yaml"), "--png", f"{tmp_path}/"])
    out, err = capsys.readouterr()
    assert code == 2 and out == "", out
    assert err.count("\n") == 1 and "is a directory" in err
