"""``secure3d paper``: every experiment of the paper, regenerated in one call.

- the 1D example's reactive set (section "Problem description"): the stopping interval against
  simulated manoeuvres (:mod:`secure3d.reactive.one_d`);
- the passages (Fig. ThreadNeedle): ``maps/paper_passage_50cm.yaml`` and ``..._20cm.yaml``, both
  planners, open loop;
- the blind corner (Figs. BasePlanner and Gplanner): ``maps/paper_blind_corner.yaml``, both
  planners, open loop (the planned trajectory) and closed loop (the realised path, the detection
  point, the outcome).

Writes figures laid out like the paper's (the two passages side by side; per corner planner, the
planned and the realised trajectory side by side), Rerun recordings, and
``paper.md``: the paper's figures against ours (final times, solve times, outcomes). Every file is
written atomically. The paper's solve times are MATLAB fmincon (SQP) on a 3.7 GHz Xeon E5-1630.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np

from secure3d.outputs import atomic_write_text
from secure3d.planning.problem import Planner

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.planning.collocation import NLPCache
    from secure3d.planning.result import PlanResult
    from secure3d.simulation.results import SimResult
    from secure3d.world.spec import Scenario

#: The shipped scenario files of the paper's experiments.
MAPS = Path(__file__).resolve().parent / "maps"
#: The paper's planned final times (s) of the secure planner through each passage.
PAPER_PASSAGES = {"paper_passage_50cm": 1.60, "paper_passage_20cm": 2.12}
#: The paper's planned final times (s) on the blind corner.
PAPER_CORNER = {"secure": 2.50, "baseline": 1.67}
#: The paper's solve-time ranges (fmincon), by experiment and planner.
PAPER_SOLVE = {
    "passage": {"secure": "4-6 s", "baseline": "1.5-3 s"},
    "corner": {"secure": "55-100 s", "baseline": "12-25 s"},
}
#: The paper's closed-loop outcomes on the blind corner.
PAPER_OUTCOME = {"secure": "stopped safely", "baseline": "collided"}
#: How the corner is flown, as in the paper's Algorithm 1: when a frame breaks the plan the
#: reactive controller takes over at once (no replan in flight, which lets a baseline swerve round
#: what it has just seen), with the planner's default 8 obstacle slots per node as in open loop,
#: so that each robot flies the plan the open-loop rows report. (With the closed loop's 12 the
#: outcomes are the same: the baseline hits the box at 0.99 m/s, the secure robot reaches the goal
#: in 1.97 s on another local optimum; the baseline's first plan then takes three starts, 6.8 s.)
CORNER_FLIGHT = MappingProxyType({"obstacle_slots": 8, "replan_in_flight": False})
COLUMNS = (
    "experiment",
    "planner",
    "paper T",
    "our T",
    "paper solve",
    "our solve",
    "paper outcome",
    "our outcome",
)


@dataclass(frozen=True)
class Row:
    """One line of the comparison table (times in s; None: not reported)."""

    experiment: str
    planner: str
    paper_time: float | None
    time: float | None
    paper_solve: str
    solve: float | None
    paper_outcome: str
    outcome: str

    def cells(self) -> list[str]:
        def sec(value: float | None) -> str:
            return "-" if value is None else f"{value:.2f} s"

        return [
            self.experiment,
            self.planner,
            sec(self.paper_time),
            sec(self.time),
            self.paper_solve,
            sec(self.solve),
            self.paper_outcome,
            self.outcome,
        ]


@dataclass
class PaperRun:
    """What :func:`run_paper` produced: table rows and written files."""

    rows: list[Row]
    files: list[Path]

    def markdown(self, quick: bool) -> str:
        head = "| " + " | ".join(COLUMNS) + " |\n|" + "---|" * len(COLUMNS) + "\n"
        body = "".join("| " + " | ".join(r.cells()) + " |\n" for r in self.rows)
        note = " (--quick: 20 collocation nodes, coarser plans)" if quick else ""
        return (
            f"# The paper's experiments, regenerated{note}\n\n"
            "T: planned final time (open loop) or time to the goal (closed loop). Paper solve"
            " times: MATLAB fmincon (SQP), Xeon E5-1630 3.7 GHz; ours: IPOPT time of the plan"
            " (every start and retry; closed loop: the first plan).\n\n" + head + body
        )


def one_d_example(out: Path) -> tuple[Row, Path]:
    """The 1D example: S_r(x) = [x1, x1 + x2|x2|/2] against simulated stops (paper Def. 1)."""
    from matplotlib.figure import Figure

    from secure3d.reactive import one_d
    from secure3d.viz.figures import save_figure

    speeds = np.linspace(-2.0, 2.0, 9)
    x0 = np.stack([np.zeros_like(speeds), speeds], axis=1)
    closed = one_d.stopping_interval(x0)
    simulated = one_d.reactive_set(x0, np.array([-5.0, 5.0]), law="stop", dt=0.001)
    error = float(np.abs(closed - simulated).max())
    fig = Figure(figsize=(6.0, 4.0))
    ax = fig.add_subplot(1, 1, 1)
    for v, (lo, hi), (slo, shi) in zip(speeds, closed, simulated, strict=True):
        ax.plot([lo, hi], [v, v], color="tab:green", lw=6, alpha=0.4)
        ax.plot([slo, shi], [v, v], color="black", lw=1.2)
    ax.set_xlabel("position x1 (m)")
    ax.set_ylabel("initial speed x2 (m/s)")
    ax.set_title(
        f"1D reactive sets: closed form (green) vs simulated stops (max error {error:.3f} m)"
    )
    path = save_figure(fig, out / "one_d_reactive_sets.png")
    row = Row(
        "1D reactive set",
        "-",
        None,
        None,
        "-",
        None,
        "S_r = stopping interval",
        f"max error {error:.3f} m",
    )
    return row, path


def _plan_rrd(scenario: Scenario, plans: list[PlanResult], path: Path) -> Path:
    from secure3d.viz.rerun_log import RerunRecorder

    with RerunRecorder(path, recording_name=scenario.name) as rec:
        rec.log_world(true_boxes=scenario.world.boxes, bounds=scenario.world.bounds)
        for plan in plans:
            if len(plan.positions):
                rec.log_plan(0.0, plan)
    return path


def _plan_panel(scenario: Scenario, plans: list[PlanResult], title: str) -> dict:
    """draw_top_down's arguments for planned trajectories with their reactive sets."""
    return {
        "bounds": scenario.world.bounds,
        "true_boxes": scenario.world.boxes,
        "hidden_names": scenario.hidden_obstacles,
        "plans": [p for p in plans if len(p.positions)],
        "start": np.asarray(scenario.start.position),
        "goal": np.asarray(scenario.goal.position),
        "title": title,
    }


def _flight_panel(scenario: Scenario, result: SimResult, title: str) -> dict:
    """draw_top_down's arguments for a flight: realised path, detection point, collision."""
    panel = _plan_panel(scenario, [p for _, p in result.plans[:1]], title)
    panel["realised_paths"] = {result.planner: result.positions}
    if result.detection_point is not None:
        panel["detection_points"] = {result.planner: result.detection_point}
    panel["collision_points"] = [result.positions[-1]] if result.collided else []
    return panel


def _plan_both(scenario: Scenario, options: dict, cache: NLPCache) -> list[PlanResult]:
    from secure3d.planning import plan

    return [plan(scenario, planner, cache=cache, **options) for planner in Planner]


def passages(out: Path, options: dict, progress: Callable[[str], None]) -> PaperRun:
    """Both passages, both planners, open loop: a figure and a recording per passage."""
    from secure3d.planning import NLPCache
    from secure3d.viz.figures import top_down_panels
    from secure3d.viz.speed_figure import speed_profile_figure
    from secure3d.world import load_scenario

    run = PaperRun([], [])
    cache = NLPCache()
    speeds, panels = {}, []
    for name, paper_time in PAPER_PASSAGES.items():
        progress(f"{name}: planning (secure, baseline)")
        scenario = load_scenario(MAPS / f"{name}.yaml")
        plans = _plan_both(scenario, options, cache)
        for p in plans:
            run.rows.append(
                Row(
                    name,
                    p.planner,
                    paper_time if p.planner == Planner.SECURE else None,
                    p.final_time if p.ok else None,
                    PAPER_SOLVE["passage"][p.planner],
                    p.solve_time,
                    "reached goal",
                    _plan_outcome(p),
                )
            )
            progress(f"{name}: {p.planner} {p.status.value}, T {p.final_time:.2f} s")
        # the paper's figure: the secure plan and its reactive sets (the baseline's would hide them)
        width = name.rsplit("_", 1)[-1]
        title = f"({'ab'[len(panels)]}) {width}: secure plan, T {plans[0].final_time:.2f} s"
        panels.append(_plan_panel(scenario, plans[:1], f"{title} (paper {paper_time:.2f} s)"))
        run.files.append(_plan_rrd(scenario, plans, out / f"{name}.rrd"))
        if plans[0].ok:
            speeds[f"secure, {width}"] = (plans[0].times, plans[0].speeds)
    run.files.append(top_down_panels(panels, out_path=out / "passages.png"))
    if speeds:
        # the paper's "smaller velocity arrows" in the narrower passage, as speed over time
        title = "secure plans through the passages: slower in the narrower one"
        run.files.append(speed_profile_figure(speeds, out / "passages_speed.png", title=title))
    return run


def _plan_outcome(plan: PlanResult) -> str:
    if not plan.ok:
        return plan.status.value
    return "certified plan" if plan.planner == Planner.SECURE else "plan"


def _closed_loop_outcome(result: SimResult) -> str:
    if result.collided:
        impact = float(np.interp(result.collision_time, result.times, result.speeds))
        return f"collided at {impact:.2f} m/s"
    seen = "saw the obstacle, " if result.detection_time is not None else ""
    stops = f"{result.takeovers} take-over(s), " if result.takeovers else ""
    return f"{seen}{stops}{result.outcome}"


def blind_corner(out: Path, options: dict, progress: Callable[[str], None]) -> PaperRun:
    """The blind corner: both plans (open loop), then both flights (closed loop)."""
    from secure3d.planning import NLPCache
    from secure3d.session import fly_planners
    from secure3d.world import load_scenario

    scenario = load_scenario(MAPS / "paper_blind_corner.yaml")
    run = PaperRun([], [])
    progress("paper_blind_corner: planning (secure, baseline)")
    plans = _plan_both(scenario, options, NLPCache())
    by_planner = {p.planner: p for p in plans}
    for p in plans:
        run.rows.append(
            Row(
                "blind corner, open loop",
                p.planner,
                PAPER_CORNER[p.planner],
                p.final_time if p.ok else None,
                PAPER_SOLVE["corner"][p.planner],
                p.solve_time,
                "-",
                _plan_outcome(p),
            )
        )
    progress("paper_blind_corner: flying both planners in closed loop")
    results = fly_planners(
        scenario,
        ("secure", "baseline"),
        0,
        rrd=lambda planner: out / f"corner_{planner}.rrd",
        report=lambda r: progress(f"paper_blind_corner: {r.planner} {r.outcome}"),
        **{**CORNER_FLIGHT, **options},
    )
    for r in results:
        first_solve = r.solve_times[0] if len(r.solve_times) else None
        run.rows.append(
            Row(
                "blind corner, closed loop",
                r.planner,
                None,
                r.time_to_goal,
                PAPER_SOLVE["corner"][r.planner],
                first_solve,
                PAPER_OUTCOME[r.planner],
                _closed_loop_outcome(r),
            )
        )
        run.files.append(r.outputs["rrd"])
        run.files.append(_corner_figure(scenario, by_planner[r.planner], r, out))
    return run


def _corner_figure(scenario: Scenario, plan: PlanResult, flight: SimResult, out: Path) -> Path:
    """The paper's Fig. BasePlanner / Gplanner: (a) planned trajectory, (b) realised trajectory."""
    from secure3d.viz.figures import top_down_panels

    planned = f"(a) {plan.planner}: planned trajectory, T {plan.final_time:.2f} s"
    planned += f" (paper {PAPER_CORNER[plan.planner]:.2f} s)"
    realised = f"(b) realised trajectory: {_closed_loop_outcome(flight)}"
    panels = [_plan_panel(scenario, [plan], planned), _flight_panel(scenario, flight, realised)]
    return top_down_panels(panels, out_path=out / f"corner_{plan.planner}.png")


def run_paper(
    out: str | Path, *, quick: bool = False, progress: Callable[[str], None] = lambda s: None
) -> PaperRun:
    """Run every experiment of the paper; write figures, recordings and ``paper.md`` into ``out``.

    Parameters
    ----------
    out : output folder (created if missing).
    quick : 20 collocation nodes instead of the scenarios' 40 (for a smoke test).
    progress : called with one line per step (the CLI prints them on stderr).

    Returns
    -------
    PaperRun
        The table's rows and every file written (``paper.md`` last).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    options = {"nodes": 20} if quick else {}
    progress("1D example: reactive sets")
    row, figure = one_d_example(out)
    run = PaperRun([row], [figure])
    for part in (passages(out, options, progress), blind_corner(out, options, progress)):
        run.rows += part.rows
        run.files += part.files
    run.files.append(atomic_write_text(out / "paper.md", run.markdown(quick)))
    return run
