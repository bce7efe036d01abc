"""secure3d: secure minimum-time planning for aerial robots whose map cannot be trusted.

Implements Ivanov & Campbell, "Secure Minimum Time Planning Under Environmental Uncertainty":
plan only trajectories whose reactive sets S_r(x(t)) were seen in full by the camera at an earlier
time and never touch a known obstacle (the paper's problem TightProb and its NLP).

The public entry points are re-exported here lazily, so ``import secure3d`` stays cheap:

- :func:`load_scenario` / :class:`Scenario`: the scenario data model (``maps/*.yaml``);
- :func:`plan` and :func:`certify`: the planner and the independent safety certificate;
- :func:`simulate`: the closed loop (the paper's Algorithm 1).
"""

from __future__ import annotations

import importlib
import logging
from typing import TYPE_CHECKING, Any

# First, before anything imports numpy: the same kernels on CPUs with and without AVX-512.
from secure3d._numpy_kernels import hold_before_numpy as _hold_before_numpy
from secure3d._numpy_kernels import numpy_kernels as numpy_kernels

_hold_before_numpy()

# A library logs; the application decides where it goes (the CLI prints INFO to stderr).
logging.getLogger("secure3d").addHandler(logging.NullHandler())

__version__ = "0.1.0"

_EXPORTS = {
    "Scenario": "secure3d.world.spec",
    "load_scenario": "secure3d.world.scenario",
    "OccupancyMap": "secure3d.mapping.occupancy",
    "plan": "secure3d.planning.solve",
    "PlanResult": "secure3d.planning.result",
    "certify": "secure3d.planning.certificate",
    "simulate": "secure3d.session",
    "SimResult": "secure3d.simulation.closed_loop",
}

__all__ = sorted([*_EXPORTS, "numpy_kernels"])

if TYPE_CHECKING:  # pragma: no cover - the real types for checkers and IDEs
    from secure3d.mapping.occupancy import OccupancyMap as OccupancyMap
    from secure3d.planning.certificate import certify as certify
    from secure3d.planning.result import PlanResult as PlanResult
    from secure3d.planning.solve import plan as plan
    from secure3d.session import simulate as simulate
    from secure3d.simulation.closed_loop import SimResult as SimResult
    from secure3d.world.scenario import load_scenario as load_scenario
    from secure3d.world.spec import Scenario as Scenario


def __getattr__(name: str) -> Any:
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'secure3d' has no attribute {name!r}") from None
    return getattr(importlib.import_module(module), name)


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})
