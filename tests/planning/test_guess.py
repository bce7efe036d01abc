"""planning/guess.py: the initial guess reads the vehicle's capabilities, not its name."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import secure3d
from secure3d.planning import problem_from_scenario
from secure3d.planning.guess import initial_guess, look_ahead_yaw


@pytest.mark.parametrize("name", ["blind_corner.yaml", "planar_blind_corner.yaml"])
def test_the_guess_starts_at_the_start_ends_at_the_goal_and_keeps_the_speed_limit(maps_dir, name):
    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / name))
    model = problem.model
    g = initial_guess(problem)
    P = np.asarray(model.position(g.states))
    np.testing.assert_allclose(P[0], problem.start_position, atol=1e-9, err_msg=name)
    np.testing.assert_allclose(P[-1], np.asarray(problem.goal)[:3], atol=1e-6, err_msg=name)
    assert np.all(model.speed(g.states) <= model.speed_limit * (1 + 1e-9)), name
    assert g.final_time > 0
    if model.planar:  # a planar robot's guess stays at its height
        np.testing.assert_allclose(P[:, 2], problem.start_position[2], atol=1e-9, err_msg=name)


def test_a_robot_that_heads_where_it_goes_faces_the_path_tangent():
    arc = np.linspace(0.0, 4.0, 41)
    points = np.stack([arc, np.zeros_like(arc), np.ones_like(arc)], axis=1)
    points[20:, 1] = arc[20:] - arc[20]  # a 45-degree turn half way
    yaw = look_ahead_yaw(points, arc, 0.0, 0.0)
    np.testing.assert_allclose(yaw[:15], 0.0, atol=1e-12)
    np.testing.assert_allclose(yaw[25:], np.pi / 4, atol=1e-12)


def _centre_path_every_point(problem, path, pad=0.3, iterations=40):
    """centre_path as it was: every point's clearance queried on every iteration (reference)."""
    from secure3d.planning.guess import _densify

    pts, _ = _densify(path, 0.05)
    dims = 2 if problem.model.planar else 3
    r = problem.model.body_radius

    def clearance(q):
        c = np.minimum(q - problem.bounds_lo, problem.bounds_hi - q)[:, :dims].min(axis=1)
        return problem.box_index.min_distance(q, c) if len(problem.boxes_lo) else c

    steps = 1e-3 * np.eye(3)[:dims]
    for _ in range(iterations):
        inner = pts[1:-1]
        probes = [inner] + [inner + s * steps[d] for d in range(dims) for s in (1.0, -1.0)]
        c_all = clearance(np.concatenate(probes)).reshape(1 + 2 * dims, len(inner))
        grad = np.zeros_like(inner)
        for d in range(dims):
            grad[:, d] = (c_all[1 + 2 * d] - c_all[2 + 2 * d]) / 2e-3
        deficit = np.clip(r + pad - c_all[0], 0.0, None)
        if not np.any(deficit > 0.0):
            break
        push = grad * np.minimum(deficit, 0.02)[:, None]
        smooth = 0.5 * (pts[:-2] + pts[2:]) - inner
        moved = inner + push + 0.3 * smooth * (deficit > 0)[:, None]
        ok = clearance(moved) >= np.minimum(c_all[0], r)
        pts[1:-1] = np.where(ok[:, None], moved, inner)
    return pts


@pytest.mark.parametrize(
    "name", ["blind_corner.yaml", "planar_blind_corner.yaml", "narrow_passage_20cm.yaml"]
)
def test_centring_queries_only_the_points_that_move_and_gives_the_same_path(maps_dir, name):
    """centre_path re-queries only points that had a deficit (the others are frozen): the same
    path, bit for bit, as querying every point every iteration."""
    from secure3d.planning.guess import centre_path, graph_path

    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / name))
    path = graph_path(problem)
    for pad in (0.3, 0.6):
        want = _centre_path_every_point(problem, path.copy(), pad)
        np.testing.assert_array_equal(centre_path(problem, path.copy(), pad), want)


def _numpy_grid_graph(free, shape, res, edge_cost):
    """The graph as grid_route built it before the compiled kernel: 26 sliced index arrays, a COO
    matrix converted to CSR (the reference the kernel must match bit for bit)."""
    from scipy.sparse import coo_matrix

    idx = np.arange(free.size).reshape(shape)
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    rows, cols, weights = [], [], []
    for off in [np.array(o) for o in np.ndindex(3, 3, 3) if o != (1, 1, 1)]:
        o = off - 1
        if any(o[d] != 0 and shape[d] == 1 for d in range(3)):
            continue
        src = idx[
            max(0, -o[0]) : shape[0] - max(0, o[0]),
            max(0, -o[1]) : shape[1] - max(0, o[1]),
            max(0, -o[2]) : shape[2] - max(0, o[2]),
        ].ravel()
        dst = src + int(o @ strides)
        ok = free[src] & free[dst]
        rows.append(src[ok])
        cols.append(dst[ok])
        weights.append(edge_cost(src[ok], dst[ok], res * float(np.linalg.norm(o))))
    return coo_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
        shape=(free.size, free.size),
    ).tocsr()


@pytest.mark.parametrize(
    "shape",
    [(7, 9, 5), (1, 8, 6), (6, 1, 7), (5, 6, 1), (2, 2, 2), (3, 2, 4), (1, 1, 9), (11, 13, 12)],
)
def test_the_compiled_grid_graph_is_the_numpy_one_bit_for_bit(shape):
    from secure3d.planning.guess import grid_graph

    rng = np.random.default_rng(sum(shape))
    free = rng.random(int(np.prod(shape))) < 0.7
    clear = rng.random(free.size)

    def cost(src, dst, length):
        return length * (1.0 + 1.0 / (0.25 + np.maximum(np.minimum(clear[src], clear[dst]), 0.0)))

    new, old = grid_graph(free, shape, 0.13, cost), _numpy_grid_graph(free, shape, 0.13, cost)
    assert new.has_canonical_format and old.has_canonical_format
    np.testing.assert_array_equal(new.indptr, old.indptr)
    np.testing.assert_array_equal(new.indices, old.indices)
    assert np.array_equal(new.data, old.data)  # the same floats, not merely close
    assert new.nnz > 0


def _scipy_route(free, shape, res, weight, s, g):
    """The route as grid_route found it before the compiled search: scipy's dijkstra on the
    grid's CSR graph, the path read back from its predecessors (None: unreachable)."""
    from scipy.sparse.csgraph import dijkstra

    from secure3d.planning.guess import grid_graph

    def cost(src, dst, length):
        return length * np.maximum(weight[src], weight[dst])

    dist, pred = dijkstra(grid_graph(free, shape, res, cost), indices=s, return_predecessors=True)
    if not np.isfinite(dist[g]):
        return None, np.inf
    cells = [g]
    while cells[-1] != s:
        cells.append(int(pred[cells[-1]]))
    return cells[::-1], dist[g]


def test_the_compiled_grid_search_takes_scipys_route_ties_included():
    """grid_search: the cost and the very route of scipy's dijkstra on the grid graph, on grids
    with equal weights everywhere (many routes of equal cost), few distinct weights, random ones,
    axes of one or two cells, blocked cells and unreachable goals."""
    from secure3d.planning._grid_kernel import grid_search
    from secure3d.planning.guess import _OFFSET_LENGTHS, GRID_OFFSETS

    rng = np.random.default_rng(7)
    routes = unreachable = 0
    for trial in range(300):
        shape = tuple(int(x) for x in rng.integers(1, 11, 3))
        n = int(np.prod(shape))
        free = rng.random(n) < rng.uniform(0.4, 0.95)
        weight = [np.ones(n), rng.choice([1.0, 1.5, 2.0], n), 1.0 + rng.random(n)][trial % 3]
        res = float(rng.choice([0.1, 0.13, 0.25]))
        s, g = (int(c) for c in rng.integers(n, size=2))
        if s == g:
            continue
        free[s] = free[g] = True
        want, want_cost = _scipy_route(free, shape, res, weight, s, g)
        cells, cost = grid_search(
            free, np.array(shape, np.int64), GRID_OFFSETS, res * _OFFSET_LENGTHS, weight, s, g
        )
        if want is None:
            assert len(cells) == 0 and cost == np.inf
            unreachable += 1
        else:
            assert cells.tolist() == want and cost == want_cost, (trial, shape)
            routes += 1
    assert routes > 150 and unreachable > 5


def test_a_grid_route_refuses_cell_weights_that_are_not_positive():
    from secure3d.errors import PlanningError
    from secure3d.planning.guess import grid_route

    shape = (4, 3, 2)
    lo, res = np.zeros(3), 0.5
    centres = np.stack(np.meshgrid(*[np.arange(k) * res for k in shape], indexing="ij"), -1)
    free = np.ones(shape, bool)
    start, goal = np.zeros(3), np.array([1.5, 1.0, 0.5])
    path = grid_route(centres.reshape(-1, 3), lo, res, free, 1.0, start, goal)
    assert np.array_equal(path[0], start) and np.array_equal(path[-1], goal)
    for bad in (0.0, -1.0, np.nan):
        weight = np.ones(free.size)
        weight[5] = bad
        with pytest.raises(PlanningError, match="weight"):
            grid_route(centres.reshape(-1, 3), lo, res, free, weight, start, goal)


def test_the_grid_graph_names_a_free_mask_that_does_not_fit_its_shape():
    from secure3d.errors import PlanningError
    from secure3d.planning.guess import grid_graph

    def cost(src, dst, length):
        return length

    with pytest.raises(PlanningError, match="free must be 24 flat bools"):
        grid_graph(np.ones(23, bool), (2, 3, 4), 0.1, cost)
    with pytest.raises(PlanningError, match="free must be"):
        grid_graph(np.ones(24, int), (2, 3, 4), 0.1, cost)
    with pytest.raises(PlanningError, match="shape must be 3 positive"):
        grid_graph(np.ones(0, bool), (0, 3, 4), 0.1, cost)


def test_an_edge_weighs_its_nearer_ends_clearance_bit_for_bit():
    """The grid's per-cell weights: max over an edge's ends equals the weight of their smaller
    clearance, exactly (ties, inf, clearances inside the body and just above it)."""
    from secure3d.planning.guess import clearance_weight

    rng = np.random.default_rng(5)
    c = np.concatenate([rng.uniform(0.0, 2.0, 5000), [np.inf, 0.2, 0.2 + 1e-15, 0.0]])
    s, d = rng.integers(0, len(c), 20000), rng.integers(0, len(c), 20000)
    length = rng.uniform(0.1, 0.4, 20000)
    for r, pad in ((0.2, 0.15), (0.3, 0.0), (0.05, 0.6)):
        w = clearance_weight(c, r, pad)
        near = np.minimum(c[s], c[d])
        want = length * (1.0 + 1.0 / (0.25 + np.maximum(near - r, 0.0) / max(pad, 1e-3)))
        assert np.array_equal(length * np.maximum(w[s], w[d]), want)
    from secure3d.errors import PlanningError

    for r, pad in ((-0.1, 0.15), (0.2, np.nan)):
        with pytest.raises(PlanningError, match="clearance_weight"):
            clearance_weight(c, r, pad)


def _speed_caps_every_pair(problem, points, tangents, yaws, v_cap, levels=12):
    """secure_speed_caps as it was: margins for every (point, camera) pair, every seen pair's
    seven segments tested (the reference the faster one must equal)."""
    from secure3d.planning.lookback import frustum_margins, node_geometry, start_margins

    model, o = problem.model, problem.options
    n = len(points)
    speeds = np.linspace(0.0, v_cap, levels)
    X = np.stack(
        [
            model.initial_state(p, s * t, y)
            for p, t, y in zip(points, tangents, yaws, strict=True)
            for s in speeds
        ]
    )
    cams = np.stack(
        [model.initial_state(p, 0.0 * t, y) for p, t, y in zip(points, tangents, yaws, strict=True)]
    )
    geo_e, geo_c = node_geometry(problem, X), node_geometry(problem, cams)
    geo = {"C": geo_e["C"], "M": geo_e["M"], "R": geo_c["R"], "o": geo_c["o"]}
    fm = frustum_margins(problem, geo)
    owner = np.repeat(np.arange(n), levels)
    seen = (fm >= o.margin) & (np.arange(n)[None, :] < owner[:, None])
    rows, cols = np.nonzero(seen)
    tips = [geo["C"][rows]] + [
        geo["C"][rows] + s * 0.9 * geo["M"][rows, :, a] for a in range(3) for s in (1.0, -1.0)
    ]
    hit = problem.box_index.segments_blocked(np.tile(geo["o"][cols], (7, 1)), np.concatenate(tips))
    blocked = hit.reshape(7, -1).any(axis=0)
    seen[rows[blocked], cols[blocked]] = False
    ok = (seen.any(axis=1) | (start_margins(problem, geo) >= o.margin)).reshape(n, levels)
    ok[:, 0] = True
    first_bad = np.where(ok.all(axis=1), levels, np.argmin(ok, axis=1))
    return speeds[np.maximum(first_bad - 1, 0)]


@pytest.mark.parametrize("name", ["forest.yaml", "blind_corner_quadrotor.yaml", "warehouse.yaml"])
def test_secure_speed_caps_equal_testing_every_camera_pair(maps_dir, name, monkeypatch):
    """The caps (only earlier cameras' margins; the nearest clear sight found first) are those of
    testing every pair, on the guesses' own paths; and some caps are partial (the test bites)."""
    from secure3d.planning import guess as guess_mod

    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / name))
    calls = []
    real = guess_mod.secure_speed_caps

    def spy(*args, **kwargs):
        calls.append((args, kwargs))
        return real(*args, **kwargs)

    monkeypatch.setattr(guess_mod, "secure_speed_caps", spy)
    initial_guess(problem, secure=True)
    assert calls
    for (prob, points, tangents, yaws, v_cap), kwargs in calls:
        got = real(prob, points, tangents, yaws, v_cap, **kwargs)
        want = _speed_caps_every_pair(prob, points, tangents, yaws, v_cap, **kwargs)
        assert np.array_equal(got, want)
        assert 0.0 < got.min() < v_cap or name != "forest.yaml"


def test_frustum_margins_of_earlier_cameras_are_the_full_matrixs(maps_dir):
    """frustum_margins(owner=...): the full matrix's values where the camera comes before the
    ellipsoid's owner, -inf elsewhere; an owner that is not sorted is refused."""
    from secure3d.errors import PlanningError
    from secure3d.planning.lookback import frustum_margins, node_geometry

    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / "forest.yaml"))
    g = initial_guess(problem, secure=True)
    geo = node_geometry(problem, g.states)
    K = len(g.states)
    owner = np.repeat(np.arange(0, K, 4), 4)[:K]
    full, part = frustum_margins(problem, geo), frustum_margins(problem, geo, owner)
    earlier = np.arange(K)[None, :] < owner[:, None]
    # the compiled loop's sums may round apart from numpy's (einsum's fused multiply-adds)
    np.testing.assert_allclose(part[earlier], full[earlier], rtol=0, atol=1e-12)
    assert np.all(np.isneginf(part[~earlier])) and np.isfinite(full).all()
    with pytest.raises(PlanningError, match="owner"):
        frustum_margins(problem, geo, owner[::-1])
    from secure3d.planning.lookback import sight_tips

    tips = sight_tips(geo["C"], geo["M"])
    assert tips.shape == (K, 7, 3) and np.array_equal(tips[:, 0], geo["C"])
    np.testing.assert_allclose(tips[:, 1] + tips[:, 2], 2 * geo["C"], atol=1e-12)
    with pytest.raises(PlanningError, match="sight_tips"):
        sight_tips(geo["C"], geo["M"][:-1])


@pytest.mark.parametrize("name", ["blind_corner.yaml", "planar_blind_corner.yaml"])
def test_a_goal_in_the_starts_grid_cell_gets_a_route_from_the_start(maps_dir, name):
    """Start and goal in one cell of the guess's grid (a denial viewpoint 0.17 m ahead): the route
    is the segment between them. It was the one cell with the start overwritten by the goal, a path
    of no length whose tangents were NaN, and the flight stopped with an error."""
    from secure3d.planning.guess import graph_path

    problem = problem_from_scenario(secure3d.load_scenario(maps_dir / name))
    start = problem.start_position
    # A goal 0.05 m ahead, and one behind (a diff drive's guess turns round first).
    for offset in ([0.05, 0.0, 0.0], [-0.04, 0.02, 0.0]):
        goal = start + np.array(offset)
        near = dataclasses.replace(problem, goal=goal)
        path = graph_path(near)
        np.testing.assert_array_equal(path, [start, goal])
        g = initial_guess(near, secure=True)
        assert np.all(np.isfinite(g.states)) and np.all(np.isfinite(g.controls)), (name, offset)
        P = np.asarray(near.model.position(g.states))
        np.testing.assert_allclose(P[-1], goal, atol=1e-6)
        assert g.final_time > 0
        result = secure3d.plan(near, "secure")
        assert result.ok, (name, offset, result.message)
