"""The passage-width family (secure3d.world.passage_families) on the paper's passage."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from secure3d.errors import ScenarioError
from secure3d.world import load_scenario
from secure3d.world.families import family_variants
from secure3d.world.family_registry import FAMILIES
from secure3d.world.passage_families import MAX_WIDTH, MIN_SIDE_ROOM
from secure3d.world.scenario import save_scenario

MAPS = Path(__file__).resolve().parents[2] / "maps"


def _gap(scenario) -> tuple[float, float]:
    left, right = scenario.world.obstacle("wall_left"), scenario.world.obstacle("wall_right")
    return left.hi[1], right.lo[1]


def test_variants_are_passages_of_random_width_about_the_same_centre(tmp_path) -> None:
    base = load_scenario(MAPS / "paper_passage_50cm.yaml")
    variants = family_variants(FAMILIES["passage_width"], base, 20, seed=3)
    again = family_variants(FAMILIES["passage_width"], base, 20, seed=3)
    widths = []
    for v, w in zip(variants, again, strict=True):
        lo, hi = _gap(v)
        assert (lo, hi) == _gap(w), "a variant is a pure function of (base, seed, i)"
        np.testing.assert_allclose(lo + hi, 0.0, atol=1e-12, err_msg="the gap stays centred")
        widths.append(hi - lo)
        assert v.world.bounds == base.world.bounds and v.start == base.start
        assert not v.hidden_obstacles, "nothing is hidden in this family"
    narrowest = 2 * (base.vehicle.body_radius + MIN_SIDE_ROOM)
    assert narrowest <= min(widths) and max(widths) <= MAX_WIDTH
    assert max(widths) - min(widths) > 0.2, "the widths should spread over the range"
    path = save_scenario(variants[0], tmp_path / "v.yaml")
    assert _gap(load_scenario(path)) == pytest.approx(_gap(variants[0]))


def test_the_family_names_what_a_base_without_a_passage_lacks() -> None:
    base = load_scenario(MAPS / "paper_blind_corner.yaml")
    with pytest.raises(ScenarioError, match="wall_left"):
        family_variants(FAMILIES["passage_width"], base, 1, seed=0)
    passage = load_scenario(MAPS / "paper_passage_50cm.yaml")
    wide = dataclasses.replace(
        passage, vehicle=dataclasses.replace(passage.vehicle, body_radius=0.3)
    )
    with pytest.raises(ScenarioError, match="too wide"):
        family_variants(FAMILIES["passage_width"], wide, 1, seed=0)
