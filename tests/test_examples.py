"""Smoke test of examples/: each script's ``main(["--quick", "--out", DIR])`` runs headless,
returns 0, prints its report and writes the files it promises (no ``.part`` leftovers).

01 (plans only) and 07 (a two-variant baseline campaign) run in the fast suite; the closed-loop
examples fly full scenarios with both planners and are marked slow.
"""

from __future__ import annotations

import csv
import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _run(name: str, out: Path, capsys: pytest.CaptureFixture[str]) -> str:
    assert _load(name).main(["--quick", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    leftovers = [p.name for p in out.rglob("*.part")]
    assert leftovers == [], leftovers
    return text


def _written(text: str) -> list[Path]:
    """Every file the report says it wrote, checked to exist and be non-trivial."""
    paths = [Path(line.split("wrote ", 1)[1]) for line in text.splitlines() if "wrote " in line]
    for path in paths:
        assert path.stat().st_size > 1000, path
        if path.suffix == ".png":
            assert path.read_bytes().startswith(PNG_MAGIC), path
    return paths


FAST = ["01_plan_blind_corner", "07_campaign"]
SLOW = [
    "02_simulate_blind_corner",
    "03_planar_passage",
    "04_planar_blind_corner",
    "05_quadrotor_forest",
    "06_attacked_warehouse",
    "08_paper",
]


def test_every_example_is_numbered_and_smoke_tested() -> None:
    found = sorted(p.stem for p in EXAMPLES.glob("[0-9][0-9]_*.py"))
    assert found == sorted(FAST + SLOW), "add new examples to this file"


def test_01_plans_both_and_draws_them(tmp_path: Path, capsys) -> None:
    text = _run("01_plan_blind_corner", tmp_path, capsys)
    lines = text.splitlines()
    assert lines[0].startswith("secure") and any(line.startswith("baseline") for line in lines)
    assert "certificate:" in text
    assert [p.name for p in _written(text)] == ["01_blind_corner_plans.png"]


def test_07_campaign_writes_its_table(tmp_path: Path, capsys) -> None:
    text = _run("07_campaign", tmp_path, capsys)
    assert text.startswith("# Campaign: blind_corner, 2 hidden-obstacle variants")
    folder = tmp_path / "07_campaign"
    with open(folder / "campaign.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["variant"], r["planner"]) for r in rows] == [("0", "baseline"), ("1", "baseline")]
    assert (folder / "summary.md").read_text().rstrip() in text


@pytest.mark.slow
@pytest.mark.parametrize("name", SLOW)
def test_closed_loop_examples(name: str, tmp_path: Path, capsys) -> None:
    text = _run(name, tmp_path, capsys)
    written = _written(text)
    assert written, f"{name} wrote nothing"
    if name == "08_paper":
        assert "| paper_passage_20cm | secure | 2.12 s |" in text, "the paper's times are quoted"
        assert {p.suffix for p in written} == {".rrd", ".png", ".md"}
    elif name == "03_planar_passage":
        assert "paper_passage_50cm" in text and "paper_passage_20cm" in text
        assert "1.60 s" in text and "2.12 s" in text, "the paper's times are quoted"
    else:
        assert {p.suffix for p in written} == {".rrd", ".png"}
        assert "planner" in text and "secure" in text and "baseline" in text
