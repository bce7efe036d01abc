"""planning/problem.py: the Planner and Solver names and the options' checks at construction."""

from __future__ import annotations

import dataclasses

import pytest

from secure3d.errors import ConfigError
from secure3d.planning import Planner, PlannerOptions, Solver


def test_planner_and_solver_names_compare_equal_to_their_strings():
    assert Planner.SECURE == "secure" and Planner.BASELINE == "baseline"
    assert Solver.IPOPT == "ipopt" and Solver("fatrop") is Solver.FATROP
    assert f"{Planner.SECURE}" == "secure" and str(Solver.FATROP) == "fatrop"
    assert "baseline" in tuple(Planner) and "fast" not in tuple(Planner)


@pytest.mark.parametrize(
    ("field", "value", "needle"),
    [
        ("nodes", 4, r"nodes: must be an integer in \[5, 400\], got 4"),
        ("nodes", True, r"nodes: must be an integer in \[5, 400\], got True"),
        ("close_gaps", -1, "close_gaps: must be an integer >= 0, got -1"),
        ("solver", "snopt", "solver: 'ipopt' or 'fatrop', got 'snopt'"),
        ("time_limit", float("nan"), "time_limit: expected a finite number"),
    ],
)
def test_options_name_the_bad_field_and_value(field, value, needle):
    with pytest.raises(ConfigError, match=needle):
        PlannerOptions(**{field: value})


@pytest.fixture(scope="module")
def corner_problem(maps_dir):
    import secure3d
    from secure3d.planning.problem import problem_from_scenario

    return problem_from_scenario(secure3d.load_scenario(maps_dir / "blind_corner.yaml"))


def test_a_replan_counts_as_observed_only_its_region_and_the_body_along_its_manoeuvre(
    corner_problem,
):
    """with_start(region=...): the NLP's start region grows to contain S_r(x0) (node 0 must be
    feasible), but the certificate and the guard count as observed only the region and the body
    along the reactive manoeuvre from x0 (session 25: the grown box let a robot touch a wall)."""
    import numpy as np

    from secure3d.planning.certificate import state_margin
    from secure3d.planning.problem import start_region

    p = corner_problem
    model, r = p.model, p.model.body_radius
    pos = np.asarray(model.position(p.x0), dtype=float)
    region = (pos - r - 0.01, pos + r + 0.01)  # the camera saw 1 cm round the body
    no_views = (np.zeros((0, 3, 3)), np.zeros((0, 3)))
    rest = p.with_start(p.x0, region=region)
    fitted_lo, fitted_hi = start_region(model, p.family, p.x0, 0.0)
    np.testing.assert_allclose(rest.start_region_lo, np.minimum(fitted_lo, region[0]))
    np.testing.assert_allclose(rest.observed_start[0], region[0])  # the body is inside it
    assert np.any(rest.start_region_lo < rest.observed_start[0] - 1e-3)  # the fitted slack
    assert state_margin(p.x0, rest, *no_views)[0] >= -1e-6  # at rest: the body where it is
    # moving at 1 m/s along +x: the braking path counts as observed for its own state ...
    moving = p.x0.copy()
    moving[3] = 1.0
    fly = p.with_start(moving, region=region)
    path = fly.manoeuvre_path(moving)
    assert path[:, 0].max() > region[1][0] + 0.05 - r and len(path) > 10
    np.testing.assert_allclose(fly.observed_path, path)
    np.testing.assert_allclose(fly.observed_start[1], region[1])  # the box is the region alone
    assert state_margin(moving, fly, *no_views)[0] >= -1e-6
    # ... but a faster state's longer braking leaves it, though the NLP's grown region holds it
    faster = p.x0.copy()
    faster[3] = 2.0
    grown = dataclasses.replace(fly, observed_lo=None, observed_hi=None, observed_path=None)
    grown = dataclasses.replace(
        grown,
        start_region_lo=np.minimum(
            fly.start_region_lo, start_region(model, p.family, faster, 0.0)[0]
        ),
        start_region_hi=np.maximum(
            fly.start_region_hi, start_region(model, p.family, faster, 0.0)[1]
        ),
    )
    assert state_margin(faster, grown, *no_views)[0] >= -1e-6
    assert state_margin(faster, fly, *no_views)[0] < -0.01
    # a start the old way (a cube, the take-off premise) counts its whole box
    assert rest.with_start(p.x0).observed_lo is None
    assert rest.with_start(p.x0).observed_path is None
    assert rest.with_options(start_region_radius=0.5).observed_path is None
    with pytest.raises(ConfigError, match="manoeuvre_path: x0"):
        rest.manoeuvre_path(np.zeros(2))
    with pytest.raises(ConfigError, match="observed_lo"):
        dataclasses.replace(rest, observed_hi=None)
    with pytest.raises(ConfigError, match="observed_path: expected"):
        dataclasses.replace(rest, observed_path=np.zeros((0, 3)))
    with pytest.raises(ConfigError, match="observed_path: every point"):
        dataclasses.replace(rest, observed_path=np.full((2, 3), np.nan))


def test_the_observed_region_and_the_body_count_as_a_union_not_their_bounding_box(
    corner_problem,
):
    """A replan at rest whose observed region stops inside the body (unobserved space beside it):
    the body where it is counts as observed, but not the slab the body pokes into along the
    region's whole face (session 26: that slab counted when the two were one bounding box)."""
    import numpy as np

    from secure3d.planning.certificate import state_margin

    p = corner_problem
    r = p.model.body_radius
    pos = np.asarray(p.model.position(p.x0), dtype=float)
    # the region's -x face 0.1 m inside the body; 1 m wide in y
    region = (pos + [-r + 0.1, -1.0, -r - 0.01], pos + [1.0, 1.0, r + 0.01])
    rest = p.with_start(p.x0, region=region)
    no_views = (np.zeros((0, 3, 3)), np.zeros((0, 3)))
    assert state_margin(p.x0, rest, *no_views)[0] >= -1e-6  # the body where it is
    aside = p.x0.copy()
    aside[1] += 0.6  # the same x, 0.6 m along the face: the body 0.1 m into unobserved space
    margin = state_margin(aside, rest, *no_views)[0]
    assert margin == pytest.approx(-0.1, abs=1e-6)
    inside = aside.copy()
    inside[0] += 0.1  # moved clear of the face: inside the region
    assert state_margin(inside, rest, *no_views)[0] >= -1e-6
    m = rest.start_margins(np.array([pos, pos + [0.0, 0.6, 0.0], pos + [0.05, 0.0, 0.0]]), r)
    np.testing.assert_allclose(m, [0.0, -0.1, -0.05], atol=1e-9)
    # braking diagonally from 2 m/s: the body along the path counts, its bounding box's corner not
    diagonal = p.x0.copy()
    diagonal[3:5] = np.sqrt(2.0)
    fly = p.with_start(diagonal, region=(pos - r, pos + r))
    path = fly.observed_path
    assert np.ptp(path[:, 0]) > 0.3 and np.ptp(path[:, 1]) > 0.3
    on_path, corner = path[len(path) // 2], [path[:, 0].max(), path[:, 1].min(), pos[2]]
    m = fly.start_margins(np.array([on_path, corner]), r)
    assert m[0] == pytest.approx(0.0, abs=1e-9) and m[1] < -0.1


def test_polyline_distance_is_the_distance_to_the_nearest_segment():
    import numpy as np

    from secure3d.errors import GeometryError
    from secure3d.geometry.polytope import polyline_distance

    path = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0]])
    pts = np.array([[0.5, 0.3, 0], [2, 0.5, 0], [-1, 0, 0], [1, 2, 2], [0.5, 0, 0]])
    np.testing.assert_allclose(
        polyline_distance(pts, path), [0.3, 1.0, 1.0, np.sqrt(5.0), 0.0], atol=1e-12
    )
    np.testing.assert_allclose(polyline_distance(pts, path[:1]), np.linalg.norm(pts, axis=1))
    rng = np.random.default_rng(3)
    walk = np.cumsum(rng.normal(size=(40, 3)), axis=0)
    walk[5] = walk[4]  # a repeated vertex (zero-length segment)
    q = rng.normal(size=(300, 3)) * 4
    t = np.linspace(0, 1, 2001)[:, None, None]
    dense = (walk[:-1][None] + t * np.diff(walk, axis=0)[None]).reshape(-1, 3)
    brute = np.linalg.norm(q[:, None] - dense[None], axis=2).min(axis=1)
    got = polyline_distance(q, walk)
    assert np.all(got <= brute + 1e-12) and np.all(brute - got < 5e-3)
    # the compiled loop is the (points x segments) numpy form it replaced, to rounding
    a, d = walk[:-1], np.diff(walk, axis=0)
    rel = q[:, None, :] - a[None]
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(np.einsum("ksj,sj->ks", rel, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    gap = rel - t[..., None] * d[None]
    np.testing.assert_allclose(got, np.sqrt((gap**2).sum(axis=2).min(axis=1)), rtol=1e-12)
    with pytest.raises(GeometryError, match="polyline_distance: path"):
        polyline_distance(q, np.zeros((0, 3)))
    with pytest.raises(GeometryError, match=r"polyline_distance: points must be \(n, 3\) finite"):
        polyline_distance(np.array([[0.0, np.nan, 0.0]]), walk)
    with pytest.raises(GeometryError, match="polyline_distance: points"):
        polyline_distance(np.zeros(3), walk)
