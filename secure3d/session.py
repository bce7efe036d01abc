"""What a user runs: a closed-loop flight with its files, and one scenario flown by each planner.

The simulator (:mod:`secure3d.simulation`) writes no files and draws nothing; this module, at the
package's edge with the CLI, opens the Rerun recording a flight logs into
(:mod:`secure3d.viz.rerun_log`) and draws its figure (:mod:`secure3d.viz.run_figures`) from the
finished result. ``secure3d.simulate`` is :func:`simulate` here.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from secure3d.outputs import check_output_path
from secure3d.planning.problem import Planner
from secure3d.simulation.campaign_records import PLANNERS

if TYPE_CHECKING:  # pragma: no cover
    from secure3d.simulation.results import SimResult
    from secure3d.world.spec import Scenario

__all__ = ["fly_planners", "simulate"]


def simulate(
    scenario: Scenario | str | Path,
    planner: str = "secure",
    seed: int = 0,
    rrd: str | Path | None = None,
    png: str | Path | None = None,
    **kwargs: object,
) -> SimResult:
    """Fly a scenario in closed loop (the paper's Algorithm 1) and report what happened
    (:func:`secure3d.simulation.closed_loop.simulate`, whose keyword options it takes).

    Parameters
    ----------
    scenario : a Scenario or the path of a scenario YAML file.
    planner : ``"secure"`` or ``"baseline"``.
    seed : seeds the camera noise and dropout (runs are deterministic for a seed).
    rrd : write a Rerun recording of the run there (atomically); replay with ``rerun FILE.rrd``.
    png : write the top-down figure of the run there (atomically).
    **kwargs : :func:`~secure3d.simulation.closed_loop.simulate`'s options and planner options.

    Returns
    -------
    SimResult, with ``outputs`` naming the files written (``{"rrd": ..., "png": ...}``).
    """
    from secure3d.errors import SimulationError
    from secure3d.simulation import closed_loop

    if planner not in tuple(Planner):  # before any file is opened
        raise SimulationError(f"planner: must be 'secure' or 'baseline', got {planner!r}")
    if isinstance(scenario, (str, Path)):
        from secure3d.world.scenario import load_scenario

        scenario = load_scenario(scenario)
    # the output contract: a path that cannot be written fails now, not after the flight
    rrd = None if rrd is None else check_output_path(rrd, (".rrd",), "rrd")
    png = None if png is None else check_output_path(png, (".png",), "png")
    recorder = None
    if rrd is not None:
        from secure3d.viz.rerun_log import RerunRecorder, recording_id

        recorder = RerunRecorder(rrd, recording_id=recording_id(f"{scenario.name}-{planner}", seed))
    result = closed_loop.simulate(scenario, planner, seed, recorder=recorder, **kwargs)
    outputs: dict[str, Path] = {}
    if recorder is not None:
        outputs["rrd"] = recorder.close()
    if png is not None:
        from secure3d.viz.run_figures import run_figure

        outputs["png"] = run_figure(scenario, result, png)
    return dataclasses.replace(result, outputs=outputs)


def fly_planners(
    scenario: Scenario | str | os.PathLike[str],
    planners: Sequence[str] = PLANNERS,
    seed: int = 0,
    *,
    rrd: Callable[[str], str | os.PathLike[str] | None] | None = None,
    report: Callable[[SimResult], object] | None = None,
    **options: object,
) -> list[SimResult]:
    """Fly one scenario with each planner, same seed (camera noise), one NLP cache for all.

    Parameters
    ----------
    scenario : Scenario or path of a scenario YAML file.
    planners : planners to fly, in order.
    seed : simulation seed shared by every run, so the planners face the same camera noise.
    rrd : planner -> path of its Rerun recording (or None for none).
    report : called with each SimResult as soon as it is finished (e.g. to print its summary).
    **options : planner options (:class:`~secure3d.planning.problem.PlannerOptions` fields) and
        :func:`~secure3d.simulation.closed_loop.simulate`'s keyword options (``replan_latency``).
    """
    from secure3d.planning.collocation import NLPCache

    if isinstance(scenario, (str, os.PathLike)):
        from secure3d.world.scenario import load_scenario

        scenario = load_scenario(scenario)
    cache = NLPCache()
    results = []
    for planner in planners:
        path = None if rrd is None else rrd(planner)
        result = simulate(scenario, planner, seed=seed, rrd=path, cache=cache, **options)
        if report is not None:
            report(result)
        results.append(result)
    return results
