"""Compile numba's kernels and the NLP's node kernels once into the user's cache (``make warm``,
issue 17), so that the first plan or flight does not pay for compilation.

An edge of the package, like the CLI: it runs a plan and a flight, so it imports the planner and
the simulator. (It lived in :mod:`secure3d._numba_cache`, which every kernel module imports: an
import cycle through the whole package.)
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["WARM_FLIGHTS", "warm"]

#: Flights of a source checkout's ``maps/`` that :func:`warm` flies after the blind corner's, one
#: for each other shipped vehicle (the quadrotor, the paper's diff drive).
WARM_FLIGHTS = ("blind_corner_quadrotor.yaml", "planar_blind_corner.yaml")


def warm() -> float:
    """Compile (or load) the kernels of a secure plan, its certificate and a short closed-loop
    flight over a voxel map, so that the first real run does not pay for it: numba's, and the NLP
    node kernels' C libraries (:mod:`secure3d.planning.compiled_kernels`, unless
    ``$SECURE3D_KERNEL_COMPILE`` is ``off``). Returns seconds."""
    import os

    from secure3d.planning import compiled_kernels

    before = os.environ.get(compiled_kernels.MODE_ENV)
    if compiled_kernels.mode() != "off":
        os.environ[compiled_kernels.MODE_ENV] = "now"  # compile before use, and wait
    try:
        return _warm()
    finally:
        if before is None:
            os.environ.pop(compiled_kernels.MODE_ENV, None)
        else:
            os.environ[compiled_kernels.MODE_ENV] = before


def _warm() -> float:
    import time

    import numpy as np

    from secure3d.geometry._hull_near_kernel import hull_near, hull_nearest
    from secure3d.geometry.box_index import BoxIndex
    from secure3d.mapping._closing_kernel import sparse_closing
    from secure3d.mapping._packed_closing import packed_closed_boxes
    from secure3d.mapping.keys import morton_decode, morton_encode
    from secure3d.planning import NLPCache
    from secure3d.planning.solve import plan
    from secure3d.simulation.closed_loop import simulate
    from secure3d.world import load_scenario

    t0 = time.perf_counter()
    maps = Path(__file__).resolve().parents[1] / "maps"
    checkout = (maps / "office_bt.yaml").exists()  # a source checkout: its shipped scenarios
    if checkout:
        # the flight first, in a process that has loaded no kernel yet: every kernel it calls goes
        # to the manifest the next flights' set-ups preload (secure3d._kernel_manifest)
        simulate(maps / "blind_corner.yaml", "secure")
        # and one per shipped vehicle: the node kernels are compiled per model, limits and
        # reactive-set family, and without them a first quadrotor flight ran its NLPs in CasADi's
        # virtual machine (1.2x real time against 1.5x, benchmarks/results/warm_vehicles.md)
        for name in WARM_FLIGHTS:
            simulate(maps / name, "secure")
    # array forms of the key kernels, which a flight over an OctoMap calls (observed regions)
    for n in (1, 4):  # one point (contiguous columns) and several (strided columns)
        morton_decode(morton_encode(np.zeros((n, 3), np.int64)))
    # the tiled closing of sparse maps (a plan over a large, mostly empty server map)
    sparse_closing(np.array([[1, 1, 1]]), (3, 3, 3), 1)
    packed_closed_boxes(np.array([0], np.int64), 1)  # the bit-packed closing and merge
    # the slot screens through the box index (plans over >= 256 boxes)
    box = BoxIndex(np.zeros((1, 3)), np.ones((1, 3)))
    pts, reach = np.zeros((1, 1, 3)), np.zeros(1)
    hull_near(pts, reach, 1.0, box.lo, box.hi, *box.tree)
    hull_nearest(pts, reach, 1.0, 2, box.lo, box.hi, *box.tree)
    if checkout:
        plan(load_scenario(maps / "office_bt.yaml"), "secure", cache=NLPCache())
    return time.perf_counter() - t0
