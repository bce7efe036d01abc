"""The closed-loop simulator's building blocks (the paper's Algorithm 1 runs on them).

- :mod:`~secure3d.simulation.scene`: the true world as labelled triangle meshes;
- :mod:`~secure3d.simulation.camera`: :class:`DepthCamera`, Open3D ray casting (eq. SensorModel);
- :mod:`~secure3d.simulation.collision`: :class:`CollisionWorld`, python-fcl swept-capsule checks;
- :mod:`~secure3d.simulation.tracking`: :class:`Reference` and per-model feedback trackers;
- :mod:`~secure3d.simulation.closed_loop`: :func:`simulate`.

Names are exported lazily: importing this package loads neither Open3D, python-fcl nor Rerun.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "world_trimesh": "secure3d.simulation.scene",
    "obstacle_meshes": "secure3d.simulation.scene",
    "DepthCamera": "secure3d.simulation.camera",
    "DepthFrame": "secure3d.simulation.camera",
    "CollisionWorld": "secure3d.simulation.collision",
    "Reference": "secure3d.simulation.tracking",
    "TrackerGains": "secure3d.simulation.tracking",
    "make_tracker": "secure3d.simulation.tracking",
    "reference_at": "secure3d.simulation.tracking",
    "track": "secure3d.simulation.tracking",
    "simulate": "secure3d.simulation.closed_loop",
    "SimResult": "secure3d.simulation.closed_loop",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    try:
        module = _EXPORTS[name]
    except KeyError:
        raise AttributeError(f"module 'secure3d.simulation' has no attribute {name!r}") from None
    return getattr(importlib.import_module(module), name)
