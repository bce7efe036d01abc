"""benchmarks/ab_campaign.py's pairing of two trees' runs (its figures, not its flights)."""

from __future__ import annotations

import json

import pytest


@pytest.fixture(scope="module")
def ab(benchmark_module):
    """benchmarks/ab_campaign.py (see the ``benchmark_module`` fixture)."""
    return benchmark_module("ab_campaign")


def _run(seconds: float, iterations: int, goal: bool = True, ttg: float = 5.0) -> dict:
    return {
        "outcome": "reached goal" if goal else "time limit",
        "collided": False,
        "reached_goal": goal,
        "time_to_goal": ttg if goal else None,
        "plan_seconds": seconds,
        "iterations": iterations,
    }


def test_the_sign_test_is_exact_and_two_sided(ab):
    assert ab.sign_test(0, 0) == 1.0
    assert ab.sign_test(5, 5) == 1.0
    assert ab.sign_test(10, 0) == pytest.approx(2 / 2**10)
    assert ab.sign_test(0, 10) == ab.sign_test(10, 0)
    # 8 of 10: P(X <= 2) = (1 + 10 + 45) / 1024, twice
    assert ab.sign_test(8, 2) == pytest.approx(2 * 56 / 1024)
    assert all(0 < ab.sign_test(w, 12 - w) <= 1 for w in range(13))


def test_paired_figures_count_only_common_variants_and_changes(ab):
    key = [("forest:thin", i) for i in range(4)]
    before = {
        key[0]: _run(2.0, 40),
        key[1]: _run(2.0, 30),
        key[2]: _run(1.0, 20, goal=False),
        key[3]: _run(9.0, 90),
    }
    after = {
        key[0]: _run(1.0, 25, ttg=4.5),
        key[1]: _run(2.02, 30),
        key[2]: _run(3.0, 60, ttg=6.0),
    }
    d = ab.paired(before, after, 0.05)
    assert d["variants"] == 3  # variant 3 flew in one tree only
    assert d["changed"] == [key[2]]  # time limit -> goal
    assert d["at goal"] == (2, 3) and d["collisions"] == (0, 0)
    assert d["iterations"] == (90, 115)
    assert (d["fewer"], d["more"]) == (1, 1)  # 30 -> 30 is no change
    assert d["p"] == 1.0
    assert d["plan"] == pytest.approx((5.0, 6.02))
    assert (d["faster"], d["slower"]) == (1, 1)  # 2.0 -> 2.02 is a tie at 5 %; 1.0 -> 3.0 slower
    assert d["median ratio"] == pytest.approx(1.01)
    mean, moved = d["ttg"]
    assert moved == 1 and mean == pytest.approx(-0.25)  # variants 0 and 1 reached it in both
    assert len(ab.row_of("all", d)) == len(ab.HEAD)


def test_runs_are_read_by_pair_and_variant(ab, tmp_path):
    path = tmp_path / "before.jsonl"
    rows = [dict(_run(0.75, 12), pair="forest:thin", variant=0)]
    rows.append(dict(_run(1.0, 30, goal=False), pair="blind_corner:thin", variant=0))
    path.write_text("".join(json.dumps(r) + "\n" for r in rows) + "\n")
    runs = ab.read_runs(path)
    assert sorted(runs) == [("blind_corner:thin", 0), ("forest:thin", 0)]
    assert runs[("forest:thin", 0)]["iterations"] == 12
