"""OctoMap files named by a scenario (``world.octomap``, ``server_map.bt``): read once per file
version, checked, and turned into voxel boxes and colours.

Split from :mod:`secure3d.world.attacks` (which re-exports these names), so that
:mod:`secure3d.world.server_sources` can check a ``.bt`` without importing the attacks (the two
modules imported each other).
"""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.world.map_formats import OCTOMAP_SUFFIXES, not_a_tree

__all__ = [
    "MAX_BT_BYTES",
    "OCTOMAP_SUFFIXES",
    "octomap_leaves",
    "octomap_resolution",
    "octomap_voxel_boxes",
    "octomap_voxel_colors",
]

#: Largest OctoMap file we read (bytes): the shared 0.08 m building scan is 0.2 MB.
MAX_BT_BYTES = 50_000_000


def _stat_checked(path: str | os.PathLike[str], what: str) -> tuple[Path, os.stat_result]:
    p = Path(path)
    if (kind := not_a_tree(p)) is not None:
        origin = " --origin X Y Z" if kind == "point cloud" else ""
        raise ScenarioError(
            f"{what}: {p.name!r} is a {kind}, not a tree; build one with `secure3d map convert"
            f" {p.name} {p.name.split('.')[0]}.bt --resolution R{origin}` (or give it as"
            " server_map.cloud)"
        )
    if p.suffix.lower() not in OCTOMAP_SUFFIXES:
        raise ScenarioError(f"{what}: OctoMap files must be .bt or .ot (got {p.name!r})")
    try:
        stat = p.stat()
    except OSError as exc:
        raise ScenarioError(f"{what}: cannot read {p}: {exc.strerror or exc}") from None
    if stat.st_size > MAX_BT_BYTES:
        raise ScenarioError(
            f"{what}: {p} is larger than {MAX_BT_BYTES // 1_000_000} MB (got {stat.st_size} bytes)"
        )
    return p, stat


def octomap_leaves(path: str | os.PathLike[str], what: str = "octomap"):  # noqa: ANN201
    """The leaves of an OctoMap ``.bt`` or ``.ot`` file (any tree type OctoMap reads), cached per
    file version (path, modification time, size).

    Returns
    -------
    secure3d.mapping.octomap_io.Leaves

    Raises
    ------
    ScenarioError
        Unreadable, too large, not ``.bt``/``.ot``, or malformed (the reader's reason is given).
    """
    p, stat = _stat_checked(path, what)
    return _leaves(str(p.resolve()), stat.st_mtime_ns, stat.st_size, what)


def octomap_resolution(path: str | os.PathLike[str], what: str = "octomap") -> float:
    """The resolution (m) of an OctoMap file, validated as :func:`octomap_leaves` does."""
    return float(octomap_leaves(path, what).resolution)


def octomap_voxel_boxes(path: str | os.PathLike[str], what: str = "octomap") -> np.ndarray:
    """``[lo, hi]`` of every occupied leaf of an OctoMap ``.bt`` or ``.ot`` file.

    A leaf at depth d is a cube of ``2**(16 - d)`` voxels a side whose lowest key is the decoded
    Morton code of its first voxel (DESIGN.md section 5, OctoMap semantics). Results are cached
    per file version (path, modification time, size), so validating a scenario and then simulating
    it parses the file once.

    Parameters
    ----------
    path : path
        The ``.bt`` or ``.ot`` file.
    what : str
        Field path for error messages (e.g. ``"world.octomap"``).

    Returns
    -------
    (n, 2, 3) float, read-only

    Raises
    ------
    ScenarioError
        Unreadable, too large, not ``.bt``/``.ot``, or malformed (the reader's reason is given).
    """
    p, stat = _stat_checked(path, what)
    return _voxel_boxes(str(p.resolve()), stat.st_mtime_ns, stat.st_size, what)


def octomap_voxel_colors(path: str | os.PathLike[str], what: str = "octomap") -> np.ndarray | None:
    """r, g, b (n, 3) uint8 of the boxes of :func:`octomap_voxel_boxes`, row for row, for a
    colour tree (``ColorOcTree`` ``.ot``); None for files without colours."""
    leaves = octomap_leaves(path, what)
    if leaves.colors is None:
        return None
    return leaves.colors[leaves.values >= 0]


@functools.lru_cache(maxsize=8)
def _leaves(path: str, _mtime_ns: int, _size: int, what: str):  # noqa: ANN202
    from secure3d.errors import MapFormatError
    from secure3d.mapping.octomap_io import read_octomap_file

    try:
        return read_octomap_file(path, MAX_BT_BYTES)
    except OSError as exc:
        raise ScenarioError(f"{what}: cannot read {path}: {exc.strerror or exc}") from None
    except MapFormatError as exc:
        raise ScenarioError(f"{what}: {path} is not a valid OctoMap: {exc}") from None


@functools.lru_cache(maxsize=8)
def _voxel_boxes(path: str, mtime_ns: int, size: int, what: str) -> np.ndarray:
    from secure3d.mapping.keys import TREE_DEPTH, TREE_MAX_VAL, morton_decode

    leaves = _leaves(path, mtime_ns, size, what)
    occupied = leaves.values >= 0  # OctoMap: log-odds >= 0 (a .bt's +1/-1 alike)
    keys = morton_decode(leaves.starts[occupied])
    side = (2 ** (TREE_DEPTH - leaves.depths[occupied].astype(np.int64))) * leaves.resolution
    lo = (keys - TREE_MAX_VAL) * leaves.resolution
    boxes = np.stack([lo, lo + side[:, None]], axis=1)
    boxes.flags.writeable = False
    return boxes
