"""Fuzzing scenario files: every mutation of a shipped file is a valid scenario or one ScenarioError
line, in bounded time; alias structures never expand."""

from __future__ import annotations

import copy
import math
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from secure3d.errors import ScenarioError
from secure3d.world.scenario import load_scenario, scenario_from_dict

MAPS = Path(__file__).resolve().parents[2] / "maps"
BASES = ("blind_corner", "forest", "warehouse", "planar_passage_50cm", "beam_3d", "mesh_server")
_DATA = {name: yaml.safe_load((MAPS / f"{name}.yaml").read_text()) for name in BASES}

leaf = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=30),
    st.sampled_from([math.nan, -0.0, 1e-300, 1e300, "../../x", "", "hide", "point_mass"]),
)
values = st.recursive(
    leaf,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=3)
    ),
    max_leaves=8,
)


def _paths(node: object, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


@st.composite
def mutated(draw):
    name = draw(st.sampled_from(BASES))
    data = copy.deepcopy(_DATA[name])
    for _ in range(draw(st.integers(1, 3))):
        paths = [p for p in _paths(data) if p]
        path = draw(st.sampled_from(paths))
        parent = data
        for key in path[:-1]:
            parent = parent[key]
        action = draw(st.sampled_from(["replace", "delete", "add"]))
        if action == "delete":
            del parent[path[-1]]
        elif action == "add" and isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=8))] = draw(values)
        else:
            parent[path[-1]] = draw(values)
    return name, data


@settings(
    max_examples=150,
    deadline=5000,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(mutated())
def test_a_mutated_scenario_is_valid_or_one_scenario_error_line(case):
    name, data = case
    try:
        scenario_from_dict(data, MAPS, label=f"{name}.yaml")
    except ScenarioError as exc:
        text = str(exc)
        assert "\n" not in text and len(text) < 1000, text


@settings(max_examples=40, deadline=5000)
@given(
    depth=st.integers(2, 12),
    width=st.integers(2, 12),
    key=st.sampled_from(["max_accel", "hfov", "position", "lo"]),
)
def test_alias_structures_are_refused_or_small(tmp_path_factory, depth, width, key):
    items = ["&a0 [" + ", ".join(["1"] * width) + "]"]
    for k in range(1, depth):
        items.append(f"&a{k} [" + ", ".join([f"*a{k - 1}"] * width) + "]")
    bomb = "[" + ", ".join(items) + "]"
    text = (MAPS / "blind_corner.yaml").read_text()
    text = text.replace("limits: {max_accel: 4.0, max_speed: 4.0}", f"limits: {{{key}: {bomb}}}")
    path = tmp_path_factory.mktemp("alias") / "alias.yaml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert "\n" not in str(info.value)
