"""The sensor model and the vocabulary of :class:`~secure3d.mapping.occupancy.OccupancyMap`:
OctoMap's hit/miss log-odds with clamping (:class:`OccupancyParams`), what one scan did
(:class:`InsertStats`) and how far a voxel's state is trusted (:class:`Trust`).

Re-exported by :mod:`secure3d.mapping.occupancy` and :mod:`secure3d.mapping`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from numpy.typing import NDArray

from secure3d.errors import ConfigError
from secure3d.validation import is_real

__all__ = ["InsertStats", "OccupancyParams", "Trust"]


def _logodds(p: float) -> np.float32:
    """OctoMap's ``logodds``: computed in double, stored as float."""
    return np.float32(math.log(p / (1.0 - p)))


@dataclass(frozen=True)
class OccupancyParams:
    """OctoMap's sensor model; the defaults are OctoMap's.

    Attributes
    ----------
    prob_hit : float
        Probability that a voxel containing a measured end point is occupied (0.7 = +0.85
        log-odds per hit). Must be in (0.5, 1).
    prob_miss : float
        Probability that a voxel a beam passes through is occupied (0.4 = -0.41 log-odds per
        miss). Must be in (0, 0.5).
    occupancy_threshold : float
        A voxel is occupied when its probability is at least this (0.5 = log-odds 0).
    clamp_min, clamp_max : float
        Log-odds are clamped to these probabilities (0.1192 = -2.0, 0.971 = +3.51 log-odds) so
        the map can change its mind. ``0 < clamp_min < occupancy_threshold <= clamp_max < 1``.
    """

    prob_hit: float = 0.7
    prob_miss: float = 0.4
    occupancy_threshold: float = 0.5
    clamp_min: float = 0.1192
    clamp_max: float = 0.971

    def __post_init__(self) -> None:
        for name in ("prob_hit", "prob_miss", "occupancy_threshold", "clamp_min", "clamp_max"):
            v = getattr(self, name)
            if not is_real(v) or not 0.0 < v < 1.0:
                raise ConfigError(f"OccupancyParams.{name}: must be a number in (0, 1), got {v!r}")
        if not self.prob_hit > 0.5:
            raise ConfigError(f"OccupancyParams.prob_hit: must exceed 0.5, got {self.prob_hit!r}")
        if not self.prob_miss < 0.5:
            raise ConfigError(
                f"OccupancyParams.prob_miss: must be below 0.5, got {self.prob_miss!r}"
            )
        if not self.clamp_min < self.occupancy_threshold <= self.clamp_max:
            raise ConfigError(
                "OccupancyParams: need clamp_min < occupancy_threshold <= clamp_max, got "
                f"{self.clamp_min!r}, {self.occupancy_threshold!r}, {self.clamp_max!r}"
            )

    @property
    def hit_log(self) -> np.float32:
        return _logodds(self.prob_hit)

    @property
    def miss_log(self) -> np.float32:
        return _logodds(self.prob_miss)

    @property
    def threshold_log(self) -> np.float32:
        return _logodds(self.occupancy_threshold)

    @property
    def clamp_min_log(self) -> np.float32:
        return _logodds(self.clamp_min)

    @property
    def clamp_max_log(self) -> np.float32:
        return _logodds(self.clamp_max)


@dataclass(frozen=True)
class InsertStats:
    """What one :meth:`OccupancyMap.insert_point_cloud` did.

    Attributes
    ----------
    points_used : int
        Points whose ray was inserted (including beams clipped at the maximum range).
    skipped_nonfinite : int
        Points with NaN/inf coordinates (for depth images also invalid pixels), ignored.
    skipped_out_of_range : int
        Points whose end falls outside the key range (+-32768 voxels), ignored whole as OctoMap.
    clipped : int
        Beams longer than the maximum range: they only cleared space.
    voxels_free : int
        Voxels updated as free (each once).
    voxels_occupied : int
        Voxels updated as occupied (each once; occupied wins over free within a scan).
    occupied_codes : (voxels_occupied,) int64
        Their Morton codes: the only voxels this scan can have turned into known obstacles (a
        miss only ever lowers a voxel's log-odds).
    rays : int
        Rays cast: ``points_used``, or the distinct end voxels when discretised.
    """

    points_used: int
    skipped_nonfinite: int
    skipped_out_of_range: int
    clipped: int
    voxels_free: int
    voxels_occupied: int
    occupied_codes: NDArray[np.int64] = field(
        default_factory=lambda: np.empty(0, np.int64), repr=False, compare=False
    )
    rays: int = 0

    @property
    def voxels_updated(self) -> int:
        return self.voxels_free + self.voxels_occupied


class Trust(IntEnum):
    """What we know about a voxel, from least to most trusted source."""

    UNKNOWN = 0
    CLAIMED_FREE = 1
    CLAIMED_OCCUPIED = 2
    SENSED_FREE = 3
    SENSED_OCCUPIED = 4
