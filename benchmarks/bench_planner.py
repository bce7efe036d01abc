"""Benchmark the secure planner and its baseline on every scenario in ``maps/`` (issue #5, item 4).

For each scenario, planner (``secure``, ``baseline``) and solver (``ipopt``, ``fatrop``, and
``ipopt1s``: IPOPT with the opt-in one-sided separation duals), each of
``--reps`` repetitions does

- a *cold* solve: a fresh :class:`~secure3d.planning.NLPCache`, so the NLP is built (transcribed and
  compiled) and then solved; build and solve seconds are the planner's own ``build_time`` and
  ``solve_time``, *total* is the wall time of the whole ``plan_problem`` call (graph-search guess,
  node kernels, look-back rounds and, for the secure planner, the certificate included);
- a *warm replan*: same cache, start moved ``--replan-dt`` seconds along the cold plan
  (``problem.with_start(x(dt), region=<the start region>)``, ``warm=cold, warm_time=dt``): the
  previous plan's later nodes are kept as they are, the passed ones spread over the gap.

Tables report medians over the repetitions: final time, build, solve and total seconds, solver
iterations, the certificate's verdict and smallest margin (baseline plans are certified after the
fact, outside the timings, to show whether they happen to be secure). Two sweeps on
``--sweep-scenario`` (default ``blind_corner``) show how the cost grows: collocation nodes K
(20, 40, 80) and extra obstacles known to the server (0, 5, 10, 20 floor bumps and ceiling
stalactites that leave the middle of the corridor free). Then the issue's targets and the paper's
planar diff-drive numbers are set beside ours.

A solver that cannot handle a planner yet (fatrop's structure detection) is reported as ``n/a``
with its error, never a crash. Run::

    .venv/bin/python benchmarks/bench_planner.py [--reps 3] [--out results/planner.md]
    .venv/bin/python benchmarks/bench_planner.py --quick    # smoke test: one scenario, one rep
    .venv/bin/python benchmarks/bench_planner.py --from-json results/planner.json   # re-render

Times are wall-clock seconds on a possibly shared machine: the JSON keeps every repetition with
its CPU time and the load average before and after the run.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import sys
from collections import Counter
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

# Run as a script, so its own folder is on sys.path and the helpers beside it import directly.
from _common import (
    REPO,
    atomic_write_json,
    atomic_write_text,
    captured_native_output,
    error_text,
    fmt,
    machine_info,
    markdown_table,
    nanmedian,
    timed,
)
from tqdm import tqdm

from secure3d.planning import (
    NLPCache,
    PlanningProblem,
    certify,
    plan_problem,
    problem_from_scenario,
)
from secure3d.planning.trajectory import interpolate
from secure3d.world.scenario import load_scenario
from secure3d.world.spec import Box, Scenario

PLANNERS = ("baseline", "secure")
SOLVERS = ("ipopt", "fatrop", "ipopt1s")
#: Planner options behind each solver label ("ipopt1s": IPOPT with one-sided separation duals).
SOLVER_OPTIONS = {
    "ipopt": {"solver": "ipopt"},
    "fatrop": {"solver": "fatrop"},
    "ipopt1s": {"solver": "ipopt", "one_sided_duals": True},
}
K_VALUES = (20, 40, 80)
OBSTACLE_COUNTS = (0, 5, 10, 20)
QUICK_K_VALUES = (20,)
QUICK_OBSTACLE_COUNTS = (5,)

#: The issue's targets for ``blind_corner`` (point mass, K = 40): cold secure solve median (s),
#: warm replan solve median (s), secure / baseline cold solve-time ratio.
TARGET_COLD_SOLVE = 0.5
TARGET_WARM_SOLVE = 0.1
TARGET_SOLVE_RATIO = 2.0
TARGET_NODES = 40

#: The paper's numbers (MATLAB fmincon): secure solve times (s), secure / baseline solve-time ratio,
#: planar final times (s).
PAPER_SOLVE_BLIND_CORNER = "55-100 s"
PAPER_SOLVE_PASSAGE = "4-6 s"
PAPER_SOLVE_RATIO = "5-6x"
PAPER_PASSAGE_50 = 1.60
PAPER_PASSAGE_20 = 2.12
PAPER_CORNER_SECURE, PAPER_CORNER_BASELINE = 2.50, 1.67

#: Extra obstacles of the obstacle sweep: square bumps standing on the floor or hanging from the
#: ceiling, footprint (m) and height (m). The middle of a 2.5 m corridor stays free, so they never
#: block the path, yet sit within the planner's 1.5 m obstacle radius of it and fill its slots.
BUMP_SIDE = 0.4
BUMP_HEIGHT = 0.35
#: Horizontal distance (m) kept between a bump and the start or goal, and between two bumps.
BUMP_CLEAR_ENDS = 0.8
BUMP_SPACING = 0.3
#: Candidate positions drawn for the bumps (most fall inside walls and are rejected).
BUMP_CANDIDATES = 4000


# ---- measuring -----------------------------------------------------------------------------------


def state_along(problem: PlanningProblem, result: object, t: float) -> np.ndarray:
    """The planned state at time ``t`` (the collocation interpolant), shape (nx,)."""
    x, _ = interpolate(problem.model, result.times, result.states, result.controls, np.array([t]))
    return x[0]


def _solve_record(call: object, native: list[str], builds: int) -> dict:
    """Numbers of one ``plan_problem`` call (``call`` is a :class:`_common.Timed`)."""
    rec: dict = {
        "wall": call.wall,
        "cpu": call.cpu,
        "nlp_builds": builds,
        "native_output_lines": len(native),
        "native_output_head": native[:3],
    }
    if call.error is not None:
        rec["error"] = error_text(call.error)
        return rec
    r = call.value
    cert = r.certificate
    rec.update(
        status=r.status.value,
        ok=r.ok,
        message=r.message[:300],
        final_time=r.final_time if len(r.times) else None,
        build=r.build_time,
        solve=r.solve_time,
        iterations=r.iterations,
        lookback_rule=r.lookback_rule,
        certified=None if cert is None else bool(cert.ok),
        margin=None if cert is None else float(cert.min_margin),
        first_violation=None
        if cert is None or cert.first_violation is None
        else str(cert.first_violation),
    )
    return rec


def _planned(problem: PlanningProblem, planner: str, cache: NLPCache, **warm: object) -> tuple:
    """One timed ``plan_problem`` call with CasADi's native output captured; (Timed, record)."""
    before = cache.misses
    with captured_native_output() as native:
        call = timed(lambda: plan_problem(problem, planner, cache=cache, **warm))
    return call, _solve_record(call, native, cache.misses - before)


def one_rep(problem: PlanningProblem, planner: str, replan_dt: float) -> dict:
    """A cold solve on a fresh cache, then a warm replan from ``replan_dt`` s along the plan."""
    cache = NLPCache()
    cold, rec_cold = _planned(problem, planner, cache)
    rec = {"cold": rec_cold, "warm": {"skipped": "cold solve failed"}}
    if cold.error is not None:
        return rec
    result = cold.value
    if planner == "baseline" and len(result.times) >= 2:
        check = timed(lambda: certify(result, problem))
        if check.error is None:
            rec_cold.update(
                certified=bool(check.value.ok),
                margin=float(check.value.min_margin),
                certify_wall=check.wall,
                certified_post_hoc=True,
            )
        else:
            rec_cold["certify_error"] = error_text(check.error)
    if not result.ok:
        return rec
    # The start region observed before take-off still counts as observed (the closed loop's
    # observed_box assumes it too); it grows to contain the new start's own region.
    region = (problem.start_region_lo, problem.start_region_hi)
    moved = problem.with_start(state_along(problem, result, replan_dt), region=region)
    _, rec["warm"] = _planned(moved, planner, cache, warm=result, warm_time=replan_dt)
    return rec


def _phase_summary(recs: Sequence[dict]) -> dict:
    """Medians (and worst margin, status counts) of one phase (cold or warm) over repetitions."""
    ran = [r for r in recs if "skipped" not in r]
    out: dict = {"n": len(ran)}
    if not ran:
        out["skipped"] = recs[0].get("skipped") if recs else "not run"
        return out
    errors = [r["error"] for r in ran if "error" in r]
    if errors:
        out["error"] = errors[0]
    good = [r for r in ran if "error" not in r]
    out["statuses"] = dict(Counter(r["status"] for r in good))
    for key in ("final_time", "build", "solve", "wall", "cpu", "iterations", "nlp_builds"):
        out[key] = nanmedian([r.get(key) for r in good])
    verdicts = [r["certified"] for r in good if r.get("certified") is not None]
    out["certified"] = f"{sum(verdicts)}/{len(verdicts)}" if verdicts else None
    margins = [r["margin"] for r in good if r.get("margin") is not None]
    out["margin"] = min(margins) if margins else None
    out["post_hoc"] = any(r.get("certified_post_hoc") for r in good)
    return out


def measure(problem: PlanningProblem, planner: str, reps: int, replan_dt: float) -> dict:
    """``reps`` repetitions of :func:`one_rep` and their summary; an exception in the first cold
    solve (a solver that does not support the problem) is not repeated."""
    runs = []
    for _ in range(reps):
        runs.append(one_rep(problem, planner, replan_dt))
        if "error" in runs[-1]["cold"]:
            break
    return {
        "reps": runs,
        "cold": _phase_summary([r["cold"] for r in runs]),
        "warm": _phase_summary([r["warm"] for r in runs]),
    }


# ---- the obstacle sweep's extra boxes ------------------------------------------------------------


def _free_span(scenario: Scenario) -> tuple[float, float]:
    """Floor top and ceiling bottom (m) above and below the start: the free vertical interval."""
    obstacles = (*scenario.world.boxes, *scenario.world.meshes)
    lo = np.array([o.lo for o in obstacles]).reshape(-1, 3)
    hi = np.array([o.hi for o in obstacles]).reshape(-1, 3)
    p = np.array(scenario.start.position)
    over = np.all((lo[:, :2] <= p[:2]) & (p[:2] <= hi[:, :2]), axis=1)
    below, above = over & (hi[:, 2] <= p[2]), over & (lo[:, 2] >= p[2])
    b = scenario.world.bounds
    z_lo = float(hi[below, 2].max()) if below.any() else b.lo[2]
    z_hi = float(lo[above, 2].min()) if above.any() else b.hi[2]
    return z_lo, z_hi


def extra_boxes(scenario: Scenario, n: int, seed: int = 0) -> tuple[Box, ...]:
    """``n`` bumps on the floor and the ceiling of the free space, clear of every obstacle.

    Bumps alternate floor / ceiling; each is :data:`BUMP_SIDE` wide and :data:`BUMP_HEIGHT` tall,
    at least :data:`BUMP_CLEAR_ENDS` (horizontally) from the start and the goal and
    :data:`BUMP_SPACING` from each other. The first ``m`` of ``extra_boxes(s, n)`` are
    ``extra_boxes(s, m)``, so the sweep's obstacle sets are nested.

    Raises
    ------
    ValueError
        If the free height left between the bumps cannot pass the body, or too few positions fit.
    """
    if n == 0:
        return ()
    z_lo, z_hi = _free_span(scenario)
    gap = z_hi - z_lo - 2 * BUMP_HEIGHT
    need = 2 * (scenario.vehicle.body_radius + BUMP_SPACING)
    if gap < need:
        raise ValueError(
            f"{scenario.name}: free height {z_hi - z_lo:.2f} m leaves {gap:.2f} m between floor and"
            f" ceiling bumps, less than {need:.2f} m: the bumps would block the path"
        )
    b = scenario.world.bounds
    rng = np.random.default_rng(seed)
    half = BUMP_SIDE / 2
    xy = rng.uniform(np.add(b.lo[:2], half), np.subtract(b.hi[:2], half), size=(BUMP_CANDIDATES, 2))
    on_floor = np.arange(BUMP_CANDIDATES) % 2 == 0
    z0 = np.where(on_floor, z_lo, z_hi - BUMP_HEIGHT)
    lo = np.column_stack([xy - half, z0])
    hi = np.column_stack([xy + half, z0 + BUMP_HEIGHT])
    obstacles = (*scenario.world.boxes, *scenario.world.meshes)
    o_lo = np.array([o.lo for o in obstacles]).reshape(-1, 3)
    o_hi = np.array([o.hi for o in obstacles]).reshape(-1, 3)
    hits = np.all((lo[:, None] < o_hi[None]) & (hi[:, None] > o_lo[None]), axis=2).any(axis=1)
    ends = np.array([scenario.start.position[:2], scenario.goal.position[:2]])
    near_ends = (np.linalg.norm(xy[:, None] - ends[None], axis=2) < BUMP_CLEAR_ENDS + half).any(1)
    keep = np.flatnonzero(~hits & ~near_ends)
    # Greedy spacing in draw order (so the sets are nested); floor and ceiling alternate.
    chosen: list[int] = []
    for want_floor in (i % 2 == 0 for i in range(n)):
        for c in keep:
            if on_floor[c] != want_floor or c in chosen:
                continue
            if chosen and np.min(np.abs(xy[chosen] - xy[c]).max(axis=1)) < BUMP_SIDE + BUMP_SPACING:
                continue
            chosen.append(int(c))
            break
        else:
            raise ValueError(f"{scenario.name}: only {len(chosen)} of {n} bumps fit")
    return tuple(
        Box(f"bench_bump_{i:02d}", tuple(lo[c]), tuple(hi[c])) for i, c in enumerate(chosen)
    )


def with_boxes(scenario: Scenario, boxes: tuple[Box, ...]) -> Scenario:
    """The scenario with extra true obstacles, reported by the server (no attack on them)."""
    world = dataclasses.replace(scenario.world, boxes=(*scenario.world.boxes, *boxes))
    return dataclasses.replace(scenario, world=world, name=f"{scenario.name}_plus{len(boxes)}")


# ---- running the cases ---------------------------------------------------------------------------

#: One case group: fixed labels (scenario, solver, ...) and a function building its problem.
Setup = tuple[dict, Callable[[], PlanningProblem]]


def run_cases(setups: Sequence[Setup], args: argparse.Namespace, bar: tqdm) -> list[dict]:
    """Measure every planner on every setup; a setup that cannot be built gives error rows."""
    rows = []
    for labels, make_problem in setups:
        built = timed(make_problem)
        for planner in args.planners:
            bar.set_postfix_str(" ".join(str(v) for v in labels.values()) + f" {planner}")
            row = {"scenario": labels["scenario"], "model": "?", "planner": planner, **labels}
            if built.error is not None:
                row.setdefault("nodes", 0)
                row["setup_error"] = error_text(built.error)
            else:
                problem = built.value
                row.update(
                    model=problem.model.name,
                    nodes=problem.options.nodes,
                    known_boxes=int(problem.boxes_lo.shape[0]),
                )
                row.update(measure(problem, planner, args.reps, args.replan_dt))
            rows.append(row)
            bar.update()
    return rows


def scenario_setups(paths: Sequence[Path], args: argparse.Namespace) -> list[Setup]:
    """The main table: every scenario x solver (the scenario's own K and settings)."""
    base = functools.cache(
        lambda path: problem_from_scenario(
            load_scenario(path), time_limit=args.time_limit, extra_starts=tuple(args.starts)
        )
    )
    return [
        (
            {"scenario": p.stem, "solver": s},
            lambda p=p, s=s: base(p).with_options(**SOLVER_OPTIONS[s]),
        )
        for p in paths
        for s in args.solvers
    ]


def sweep_setups(args: argparse.Namespace) -> tuple[list[Setup], list[Setup]]:
    """The K sweep and the obstacle sweep on ``--sweep-scenario`` with ``--sweep-solver``."""
    name, solver = args.sweep_scenario, args.sweep_solver
    scenario = functools.cache(lambda: load_scenario(args.maps / f"{name}.yaml"))
    base = functools.cache(lambda: problem_from_scenario(scenario(), time_limit=args.time_limit))
    bumps = functools.cache(lambda: extra_boxes(scenario(), max(args.obstacle_counts, default=0)))

    def with_bumps(n: int) -> PlanningProblem:
        variant = with_boxes(scenario(), bumps()[:n])
        return problem_from_scenario(variant, time_limit=args.time_limit, **SOLVER_OPTIONS[solver])

    k_sweep = [
        ({"scenario": name, "solver": solver, "nodes": k},
         lambda k=k: base().with_options(nodes=k, **SOLVER_OPTIONS[solver]))
        for k in args.k_values
    ]  # fmt: skip
    obstacle_sweep = [
        ({"scenario": name, "solver": solver, "extra_boxes": n}, lambda n=n: with_bumps(n))
        for n in args.obstacle_counts
    ]
    return k_sweep, obstacle_sweep


# ---- reporting -----------------------------------------------------------------------------------


def _status_cell(row: dict) -> str:
    if "setup_error" in row:
        return "error"
    cold = row["cold"]
    if "error" in cold:
        return "n/a"
    statuses = cold["statuses"]
    if len(statuses) == 1:
        return next(iter(statuses))
    return ", ".join(f"{s} {c}/{cold['n']}" for s, c in statuses.items())


def _cert_cell(phase: dict) -> str:
    c = phase.get("certified")
    if c is None:
        return "—"
    k, n = (int(v) for v in c.split("/"))
    word = "yes" if k == n else ("no" if k == 0 else c)
    return word + ("*" if phase.get("post_hoc") else "")


#: Columns shared by the main table and the sweeps.
COST_HEADERS = [
    "T (s)",
    "build (s)",
    "solve (s)",
    "total (s)",
    "iters",
    "warm build (s)",
    "warm solve (s)",
    "warm total (s)",
    "warm iters",
    "NLP builds cold/warm",
]


def _cost_cells(row: dict) -> list[str]:
    """Cells under :data:`COST_HEADERS` (medians over the repetitions)."""
    if "setup_error" in row or "error" in row["cold"]:
        return ["—"] * len(COST_HEADERS)
    c, w = row["cold"], row["warm"]
    warm = (
        ["—"] * 4
        if "skipped" in w or "error" in w
        else [fmt(w["build"], 3), fmt(w["solve"], 3), fmt(w["wall"], 3), fmt(w["iterations"], 0)]
    )
    return [
        fmt(c["final_time"]),
        fmt(c["build"], 3),
        fmt(c["solve"], 3),
        fmt(c["wall"], 3),
        fmt(c["iterations"], 0),
        *warm,
        f"{fmt(c['nlp_builds'], 0)}/{fmt(w.get('nlp_builds'), 0)}",
    ]


def main_table(rows: Sequence[dict]) -> str:
    headers = [
        "scenario",
        "model",
        "planner",
        "solver",
        "K",
        "status",
        *COST_HEADERS,
        "certified",
        "margin (m)",
    ]
    body = []
    for r in rows:
        cold = r.get("cold", {})
        body.append(
            [
                r["scenario"],
                r["model"],
                r["planner"],
                r["solver"],
                r["nodes"] or "—",
                _status_cell(r),
                *_cost_cells(r),
                _cert_cell(cold),
                fmt(cold.get("margin"), 3),
            ]
        )
    return markdown_table(headers, body, right=[False] * 6 + [True] * (len(COST_HEADERS) + 2))


def _ratio(rows: Sequence[dict], key: str, phase: str = "cold") -> dict:
    """secure / baseline median ``key`` for rows that differ only by planner."""
    by = {}
    for r in rows:
        if "setup_error" in r or "error" in r["cold"] or "skipped" in r[phase]:
            continue
        tag = (r["scenario"], r["solver"], r["nodes"], r.get("extra_boxes"))
        by.setdefault(tag, {})[r["planner"]] = r[phase].get(key)
    return {
        t: v["secure"] / v["baseline"]
        for t, v in by.items()
        if v.get("secure") and v.get("baseline")
    }


def sweep_table(rows: Sequence[dict], first: str) -> str:
    """K sweep (``first="nodes"``) or obstacle sweep (``first="extra_boxes"``)."""
    ratios = _ratio(rows, "solve")
    headers = [
        "K" if first == "nodes" else "extra boxes",
        "known boxes",
        "planner",
        "status",
        *COST_HEADERS,
        "secure/baseline solve",
    ]
    body = []
    for r in rows:
        tag = (r["scenario"], r["solver"], r["nodes"], r.get("extra_boxes"))
        ratio = fmt(ratios.get(tag)) + "x" if r["planner"] == "secure" and tag in ratios else "—"
        body.append(
            [
                r.get(first, "—"),
                r.get("known_boxes", "—"),
                r["planner"],
                _status_cell(r),
                *_cost_cells(r),
                ratio,
            ]
        )
    return markdown_table(
        headers, body, right=[True, True, False, False] + [True] * (len(COST_HEADERS) + 1)
    )


def _find(rows: Sequence[dict], scenario: str, planner: str, solver: str) -> dict | None:
    for r in rows:
        if (r["scenario"], r["planner"], r["solver"]) == (scenario, planner, solver):
            return r
    return None


def _usable(row: dict | None) -> bool:
    return row is not None and "setup_error" not in row and "error" not in row["cold"]


def _met(value: float | None, bound: float) -> str:
    if value is None or not np.isfinite(value):
        return "—"
    return "yes" if value <= bound else "NO"


def targets_table(rows: Sequence[dict], solvers: Sequence[str]) -> str:
    """The issue's targets on ``blind_corner`` (point mass, K = 40), one block per solver."""
    body = []
    for solver in solvers:
        sec = _find(rows, "blind_corner", "secure", solver)
        base = _find(rows, "blind_corner", "baseline", solver)
        if not _usable(sec):
            body.append([f"secure solve ({solver})", "n/a" if sec else "not run", "", "", ""])
            continue
        c, w = sec["cold"], sec["warm"]
        k = sec["nodes"]
        note = "" if k == TARGET_NODES else f" (K={k}, target is for K={TARGET_NODES})"
        tag = ("blind_corner", solver, k, None)
        ratio = _ratio([sec, base], "solve").get(tag) if _usable(base) else None
        t_ratio = _ratio([sec, base], "final_time").get(tag) if _usable(base) else None
        warm_ok = "skipped" not in w and "error" not in w

        body += [
            [
                f"cold secure solve, median ({solver}){note}",
                f"{fmt(c['solve'], 3)} s",
                f"<= {TARGET_COLD_SOLVE} s",
                PAPER_SOLVE_BLIND_CORNER,
                _met(c["solve"], TARGET_COLD_SOLVE),
            ],
            [
                f"cold secure total incl. build, guess, certificate ({solver})",
                f"{fmt(c['wall'], 3)} s",
                "—",
                "—",
                "—",
            ],
            [
                f"warm replan solve, median ({solver})",
                f"{fmt(w['solve'], 3)} s" if warm_ok else "—",
                f"<= {TARGET_WARM_SOLVE} s",
                "—",
                _met(w["solve"], TARGET_WARM_SOLVE) if warm_ok else "—",
            ],
            [
                f"warm replan total, NLP rebuilds {fmt(w.get('nlp_builds'), 0)} ({solver})",
                f"{fmt(w['wall'], 3)} s" if warm_ok else "—",
                "—",
                "—",
                "—",
            ],
            [
                f"secure / baseline cold solve time ({solver})",
                f"{fmt(ratio)}x",
                f"<= {TARGET_SOLVE_RATIO:g}x",
                PAPER_SOLVE_RATIO,
                _met(ratio, TARGET_SOLVE_RATIO),
            ],
            [
                f"secure / baseline final time ({solver})",
                f"{fmt(t_ratio)}x",
                "—",
                f"{PAPER_CORNER_SECURE / PAPER_CORNER_BASELINE:.2f}x",
                "—",
            ],
        ]
    return markdown_table(
        ["quantity", "ours", "target", "paper", "met"], body, right=[False, True, True, True, False]
    )


def _final_time(row: dict | None) -> tuple[float | None, str]:
    """Median cold final time (None if unavailable) and its table cell."""
    if row is None:
        return None, "not run"
    if not _usable(row):
        return None, "n/a"
    t, status = row["cold"]["final_time"], _status_cell(row)
    return t, fmt(t) + ("" if status == "success" else f" ({status})")


#: The paper's cases next to ours: scenario, paper secure T (s), paper baseline T (s), paper solve.
PAPER_CASES = (
    ("planar_passage_50cm", PAPER_PASSAGE_50, None, PAPER_SOLVE_PASSAGE),
    ("planar_passage_20cm", PAPER_PASSAGE_20, None, PAPER_SOLVE_PASSAGE),
    ("planar_blind_corner", PAPER_CORNER_SECURE, PAPER_CORNER_BASELINE, PAPER_SOLVE_BLIND_CORNER),
    ("narrow_passage_50cm", None, None, None),
    ("narrow_passage_20cm", None, None, None),
    ("blind_corner", None, None, None),
)


def reproduction_table(rows: Sequence[dict], solver: str = "ipopt") -> str:
    """The paper's planar diff-drive cases next to ours, and our 3D versions of them."""
    body = []
    for scen, p_sec, p_base, p_solve in PAPER_CASES:
        sec, base = _find(rows, scen, "secure", solver), _find(rows, scen, "baseline", solver)
        ts, cell_s = _final_time(sec)
        tb, cell_b = _final_time(base)
        ratio = ts / tb if ts and tb else None
        paper_ratio = p_sec / p_base if p_sec and p_base else None
        solve = sec["cold"]["solve"] if _usable(sec) else None
        body.append([
            scen, cell_s, cell_b, fmt(ratio), fmt(p_sec), fmt(p_base),
            fmt(paper_ratio), fmt(solve, 3), p_solve or "—",
        ])  # fmt: skip
    t50 = _final_time(_find(rows, "planar_passage_50cm", "secure", solver))[0]
    t20 = _final_time(_find(rows, "planar_passage_20cm", "secure", solver))[0]
    grows = "not run" if t50 is None or t20 is None else ("yes" if t20 > t50 else "NO")
    headers = [f"case ({solver})", "secure T (s)", "baseline T (s)", "secure/baseline",
               "paper secure T", "paper baseline T", "paper ratio", "secure solve (s)",
               "paper solve (fmincon)"]  # fmt: skip
    table = markdown_table(headers, body)
    note = f"Secure final time grows from the 50 cm to the 20 cm passage: {grows} (paper: yes)."
    return f"{table}\n\n{note}"


def failures(sections: dict[str, Sequence[dict]]) -> list[str]:
    """One line per case that raised, did not succeed, or whose warm replan failed."""
    lines = []
    for section, rows in sections.items():
        for r in rows:
            tag = f"{section}: {r['scenario']} {r['planner']} {r['solver']} K={r['nodes']}"
            if "extra_boxes" in r:
                tag += f" +{r['extra_boxes']} boxes"
            if "setup_error" in r:
                lines.append(f"{tag}: setup failed: {r['setup_error']}")
                continue
            for phase in ("cold", "warm"):
                p = r[phase]
                if "error" in p:
                    first = next(x[phase] for x in r["reps"] if "error" in x[phase])
                    printed = first.get("native_output_head") or []
                    extra = (
                        f" (the solver printed {first['native_output_lines']} lines, the first:"
                        f" {printed[0][:200]!r})"
                        if printed
                        else ""
                    )
                    lines.append(f"{tag} {phase}: {p['error']}{extra}")
                elif "skipped" not in p and set(p.get("statuses", {})) - {"success"}:
                    msgs = {
                        x[phase].get("message", "")
                        for x in r["reps"]
                        if x[phase].get("status") != "success"
                    }
                    lines.append(f"{tag} {phase}: {p['statuses']}: {'; '.join(sorted(msgs))[:300]}")
    return lines


def report(data: dict) -> str:
    """The whole markdown report from the raw results."""
    s, m0, m1 = data["settings"], data["machine"], data.get("machine_after", {})
    load = f"load average {m0['load_avg'][0]:.2f} before"
    if m1:
        load += f", {m1['load_avg'][0]:.2f} after"
    out = [
        "# Planner benchmark",
        "",
        f"Commit {m0['commit']}{' (dirty)' if m0['dirty'] else ''}, {m0['date']}, "
        f"{m0['cpus']} CPUs, "
        f"{load}; casadi {m0['casadi']}. Medians of {s['reps']} repetition(s); warm replan from "
        f"{s['replan_dt']} s along the cold plan; per-solve time limit {s['time_limit']} s.",
        "",
        "## All scenarios",
        "",
        main_table(data["main"]),
        "",
        "T: final time of the cold plan. build: NLP transcription and compilation; solve: inside "
        "the solver (all look-back rounds); total: the whole `plan_problem` call. certified: the "
        "independent certificate; `*` = a baseline plan certified after the fact (not part of the "
        "planner). margin: the certificate's smallest margin, worst over repetitions.",
    ]
    if data.get("k_sweep"):
        out += [
            "",
            f"## Cost against K ({s['sweep_scenario']}, {s['sweep_solver']})",
            "",
            sweep_table(data["k_sweep"], "nodes"),
        ]
    if data.get("obstacle_sweep"):
        out += [
            "",
            f"## Cost against known obstacles ({s['sweep_scenario']}, "
            f"{s['sweep_solver']}, K from the scenario)",
            "",
            sweep_table(data["obstacle_sweep"], "extra_boxes"),
            "",
            f"Extra boxes: {BUMP_SIDE} m square bumps, {BUMP_HEIGHT} m tall, alternately on the "
            "floor and the ceiling, known to the server; known boxes: after the belief map's "
            "voxel merge.",
        ]
    out += [
        "",
        "## Targets (issue #5) on blind_corner, point mass",
        "",
        targets_table(data["main"], s["solvers"]),
        "",
        "## The paper's diff-drive cases",
        "",
        reproduction_table(data["main"]),
    ]
    sections = {
        "main": data["main"],
        "K sweep": data.get("k_sweep", []),
        "obstacle sweep": data.get("obstacle_sweep", []),
    }
    fails = failures(sections)
    out += ["", "## Failures", ""] + ([f"- {f}" for f in fails] if fails else ["none"])
    return "\n".join(out) + "\n"


# ---- command line --------------------------------------------------------------------------------


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--maps", type=Path, default=REPO / "maps", help="scenario folder")
    p.add_argument(
        "--scenarios",
        nargs="+",
        metavar="NAME",
        help="scenario names (file stems) to run; default: every *.yaml in --maps",
    )
    p.add_argument("--planners", nargs="+", choices=PLANNERS, default=list(PLANNERS))
    p.add_argument("--solvers", nargs="+", choices=SOLVERS, default=list(SOLVERS))
    p.add_argument("--reps", type=int, default=3, help="repetitions per case (median reported)")
    p.add_argument(
        "--replan-dt",
        type=float,
        default=0.1,
        help="the warm replan starts this many seconds along the cold plan",
    )
    p.add_argument("--time-limit", type=float, default=60.0, help="wall-clock limit per solve (s)")
    p.add_argument(
        "--starts",
        nargs="*",
        type=float,
        default=[],
        help="extra cruise-speed fractions to start cold solves from (the fastest plan is kept)",
    )
    p.add_argument("--sweep-scenario", default="blind_corner")
    p.add_argument("--sweep-solver", choices=SOLVERS, default="ipopt")
    p.add_argument("--k-values", nargs="*", type=int, default=list(K_VALUES))
    p.add_argument("--obstacle-counts", nargs="*", type=int, default=list(OBSTACLE_COUNTS))
    p.add_argument("--no-sweeps", action="store_true", help="skip the K and obstacle sweeps")
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"smoke test: blind_corner only, one rep, K {QUICK_K_VALUES}, "
        f"obstacles {QUICK_OBSTACLE_COUNTS}",
    )
    p.add_argument("--out", type=Path, help="write the markdown report here (and FILE.json)")
    p.add_argument("--json", type=Path, help="raw results (default: --out with suffix .json)")
    p.add_argument("--from-json", type=Path, help="re-render the report of an earlier run")
    args = p.parse_args(argv)
    if args.reps < 1:
        p.error(f"--reps: must be >= 1 (got {args.reps})")
    if not args.replan_dt > 0:
        p.error(f"--replan-dt: must be > 0 (got {args.replan_dt})")
    if not args.time_limit > 0:
        p.error(f"--time-limit: must be > 0 (got {args.time_limit})")
    if any(k < 5 for k in args.k_values):
        p.error(f"--k-values: each must be >= 5 (got {args.k_values})")
    if any(n < 0 for n in args.obstacle_counts):
        p.error(f"--obstacle-counts: each must be >= 0 (got {args.obstacle_counts})")
    if args.quick:
        args.scenarios = args.scenarios or ["blind_corner"]
        args.reps = 1
        args.k_values, args.obstacle_counts = list(QUICK_K_VALUES), list(QUICK_OBSTACLE_COUNTS)
    if args.no_sweeps:
        args.k_values, args.obstacle_counts = [], []
    if args.json is None and args.out is not None:
        args.json = args.out.with_suffix(".json")
    return args


def scenario_paths(args: argparse.Namespace) -> list[Path]:
    paths = sorted(args.maps.glob("*.yaml"))
    if args.scenarios:
        by_name = {p.stem: p for p in paths}
        missing = [n for n in args.scenarios if n not in by_name]
        if missing:
            raise SystemExit(
                f"bench_planner: unknown scenario(s) {missing}; in {args.maps}: {sorted(by_name)}"
            )
        paths = [by_name[n] for n in args.scenarios]
    return paths


def run(args: argparse.Namespace) -> dict:
    paths = scenario_paths(args)
    n_cases = len(paths) * len(args.solvers) * len(args.planners) + len(args.planners) * (
        len(args.k_values) + len(args.obstacle_counts)
    )
    data: dict = {
        "machine": machine_info(),
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
    }
    k_sweep, obstacle_sweep = sweep_setups(args)
    with tqdm(total=n_cases, desc="planner bench", file=sys.stderr, unit="case") as bar:
        data["main"] = run_cases(scenario_setups(paths, args), args, bar)
        data["k_sweep"] = run_cases(k_sweep, args, bar)
        data["obstacle_sweep"] = run_cases(obstacle_sweep, args, bar)
    data["machine_after"] = machine_info()
    return data


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    if args.from_json is not None:
        data = json.loads(args.from_json.read_text(encoding="utf-8"))
    else:
        data = run(args)
        if args.json is not None:
            atomic_write_json(args.json, data)
    text = report(data)
    print(text)
    if args.out is not None:
        atomic_write_text(args.out, text)


if __name__ == "__main__":
    main()
