"""planning/nlp_cache.py: the table of transcriptions, the NLP key and the cache's checks."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import secure3d
from secure3d.errors import ConfigError
from secure3d.planning import NLPCache, Planner, Solver, problem_from_scenario
from secure3d.planning.collocation import build_nlp
from secure3d.planning.fatrop_transcription import build_fatrop_nlp
from secure3d.planning.kernels import node_kernels
from secure3d.planning.nlp_cache import TRANSCRIPTIONS, nlp_key, transcription


@pytest.fixture(scope="module")
def problem(maps_dir):
    return problem_from_scenario(secure3d.load_scenario(maps_dir / "blind_corner.yaml"))


def test_every_solver_has_a_registered_transcription_sharing_the_node_kernels():
    assert set(TRANSCRIPTIONS) == {s.value for s in Solver}
    assert transcription(Solver.IPOPT).build is build_nlp
    assert transcription("fatrop").build is build_fatrop_nlp
    assert all(t.kernels is node_kernels for t in TRANSCRIPTIONS.values())


def test_the_transcriptions_import_the_kernels_and_never_each_other():
    modules = {"collocation", "fatrop_transcription"}
    for name in modules:
        path = Path(secure3d.__file__).parent / "planning" / f"{name}.py"
        imported = {
            node.module.rpartition(".")[2]
            for node in ast.walk(ast.parse(path.read_text()))
            if isinstance(node, ast.ImportFrom) and node.module
        }
        assert "kernels" in imported, name
        assert not imported & (modules - {name}), f"{name} imports {imported & modules}"


def test_an_unknown_solver_has_no_transcription_and_the_error_lists_the_known_ones():
    with pytest.raises(
        ConfigError, match=r"no transcription for 'snopt' \(known: \['fatrop', 'ipopt'\]\)"
    ):
        transcription("snopt")


def test_the_key_is_the_same_for_a_planner_named_by_string_or_by_enum(problem):
    K = problem.options.nodes
    assignment = (-1,) * K
    assert nlp_key(problem, "secure", assignment) == nlp_key(problem, Planner.SECURE, assignment)
    assert nlp_key(problem, "secure", assignment) != nlp_key(problem, "baseline", assignment)


def test_prepare_refuses_an_unknown_planner_before_building_anything(problem):
    cache = NLPCache()
    with pytest.raises(ConfigError, match="planner: must be 'secure' or 'baseline', got 'fast'"):
        cache.prepare(problem, "fast")
    assert len(cache) == 0 and cache.misses == 0
