"""Regenerate the mesh and OctoMap files used by the scenarios in this folder.

Run from the repository root (needs trimesh and the dev dependency octomap-python)::

    .venv/bin/python maps/generate_assets.py            # writes meshes/* and octomaps/*
    .venv/bin/python maps/generate_assets.py --forest   # also prints forest.yaml's tree list

Everything is deterministic; the committed files are the output of this script.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import trimesh

HERE = Path(__file__).resolve().parent
#: Voxel size of the office OctoMaps (m); every office coordinate below is a multiple of it so box
#: faces fall on voxel faces.
OFFICE_RES = 0.1
OFFICE_BOUNDS = (np.array([0.0, 0.0, 0.0]), np.array([10.0, 8.0, 3.0]))
#: The office: (name, lo, hi) boxes voxelised into the true .bt. "cabinet" stands just behind the
#: door on room B's side and is missing from the server's .bt.
OFFICE_BOXES = [
    ("floor", (0.0, 0.0, 0.0), (10.0, 8.0, 0.1)),
    ("ceiling", (0.0, 0.0, 2.9), (10.0, 8.0, 3.0)),
    ("wall_west", (0.0, 0.0, 0.0), (0.2, 8.0, 3.0)),
    ("wall_east", (9.8, 0.0, 0.0), (10.0, 8.0, 3.0)),
    ("wall_south", (0.0, 0.0, 0.0), (10.0, 0.2, 3.0)),
    ("wall_north", (0.0, 7.8, 0.0), (10.0, 8.0, 3.0)),
    ("partition_south", (4.9, 0.0, 0.0), (5.1, 3.4, 3.0)),
    ("partition_north", (4.9, 4.6, 0.0), (5.1, 8.0, 3.0)),
    ("door_lintel", (4.9, 3.4, 2.2), (5.1, 4.6, 3.0)),
    ("desk_a", (1.0, 5.6, 0.0), (2.6, 6.4, 0.8)),
    ("shelf_a", (3.6, 0.2, 0.0), (4.9, 0.8, 2.0)),
    ("desk_b", (7.2, 1.0, 0.0), (8.8, 1.8, 0.8)),
    ("column", (7.0, 5.0, 0.0), (7.4, 5.4, 2.9)),
    ("cabinet", (5.6, 4.6, 0.0), (6.2, 5.4, 2.0)),
]
OFFICE_HIDDEN = {"cabinet"}


def write_meshes() -> None:
    out = HERE / "meshes"
    out.mkdir(exist_ok=True)
    # Tree trunk: 0.18 m radius, 4 m tall, base on z = 0 (place it with `translate`).
    trunk = trimesh.creation.cylinder(radius=0.18, height=4.0, sections=12)
    trunk.apply_translation([0.0, 0.0, 2.0])
    trunk.export(out / "tree_trunk.obj")
    # A stack of crates, 1.2 x 1.0 x 1.8 m with 5 cm chamfers: the convex hull of a box's corners
    # pulled in along each axis pair keeps it closed and convex.
    half = np.array([0.6, 0.5, 0.9])
    c = 0.05
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).T.reshape(-1, 3)
    pulls = np.array([[c, c, 0.0], [c, 0.0, c], [0.0, c, c]])
    points = (signs[:, None, :] * (half - pulls)[None]).reshape(-1, 3)
    crate = trimesh.convex.convex_hull(points)
    crate.apply_translation([0.0, 0.0, half[2]])
    crate.export(out / "crate_stack.obj")
    # A barrel, 0.3 m radius, 0.9 m tall, as binary PLY (a second file format for the loader).
    barrel = trimesh.creation.cylinder(radius=0.3, height=0.9, sections=16)
    barrel.apply_translation([0.0, 0.0, 0.45])
    barrel.export(out / "barrel.ply")
    for mesh in (trunk, crate, barrel):
        if not mesh.is_volume:
            raise RuntimeError("generated mesh is not a closed volume")


def _office_cells(lo: np.ndarray, hi: np.ndarray, res: float) -> np.ndarray:
    """Centres (n, 3) of the voxels of resolution ``res`` whose centre lies in [lo, hi]."""
    axes = [np.arange(a + res / 2, b, res) for a, b in zip(lo, hi, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def write_office_octomaps() -> None:
    import octomap

    out = HERE / "octomaps"
    out.mkdir(exist_ok=True)
    res = OFFICE_RES
    cells = _office_cells(*OFFICE_BOUNDS, res)
    for filename, skip in (("office_truth.bt", set()), ("office_server.bt", OFFICE_HIDDEN)):
        occupied = np.zeros(len(cells), dtype=bool)
        for name, lo, hi in OFFICE_BOXES:
            if name not in skip:
                occupied |= np.all((cells >= lo) & (cells <= hi), axis=1)
        tree = octomap.OcTree(res)
        # Every voxel of the room is known: free ones as free, so the file is a complete map.
        tree.updateNodes(cells[~occupied], False)
        tree.updateNodes(cells[occupied], True)
        tree.updateInnerOccupancy()
        tree.writeBinary(str(out / filename).encode())


def print_forest(seed: int = 7, n_trees: int = 20) -> None:
    """Sample trunk positions (min spacing 1.6 m, clear of start and goal) and print YAML."""
    rng = np.random.default_rng(seed)
    start, goal = np.array([1.5, 0.0]), np.array([20.5, 0.0])
    trees: list[np.ndarray] = []
    while len(trees) < n_trees:
        p = np.array([rng.uniform(3.0, 19.0), rng.uniform(-4.2, 4.2)])
        if min(np.linalg.norm(p - start), np.linalg.norm(p - goal)) < 2.0:
            continue
        if trees and np.min(np.linalg.norm(np.array(trees) - p, axis=1)) < 1.6:
            continue
        trees.append(p)
    trees.sort(key=lambda q: q[0])
    for i, p in enumerate(trees):
        scale = rng.choice([0.9, 1.0, 1.1])
        print(
            f"    - {{name: tree_{i:02d}, file: meshes/tree_trunk.obj,"
            f" translate: [{p[0]:.2f}, {p[1]:.2f}, 0.0], scale: {scale}}}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--forest", action="store_true", help="print forest.yaml's tree list")
    args = parser.parse_args()
    write_meshes()
    write_office_octomaps()
    if args.forest:
        print_forest()
    for path in sorted((HERE / "meshes").iterdir()) + sorted((HERE / "octomaps").iterdir()):
        print(f"{path.relative_to(HERE)}: {path.stat().st_size} bytes")


if __name__ == "__main__":
    main()
