"""Fixtures of the planning tests."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest


def _hull_box_pairs(
    rng: np.random.Generator, n: int, los_fraction: float
) -> tuple[np.ndarray, ...]:
    """``n`` random (line-of-sight hull or ellipsoid, box) pairs as ``box_pair_distances`` takes
    them: origins, centres (n, 3), shapes (n, 3, 3), lo, hi (n, 3), los (n,) (a hull with
    probability ``los_fraction``, else the ellipsoid alone, its origin its centre)."""
    a = rng.normal(0.0, 0.4, (n, 3, 3))
    shapes = a @ a.transpose(0, 2, 1) + 0.01 * np.eye(3)
    centres = rng.uniform(-3, 3, (n, 3))
    los = rng.random(n) < los_fraction
    origins = np.where(los[:, None], rng.uniform(-3, 3, (n, 3)), centres)
    lo = rng.uniform(-3, 3, (n, 3))
    hi = lo + rng.uniform(0.02, 1.0, (n, 3))
    return origins, centres, shapes, lo, hi, los


@pytest.fixture
def hull_box_pairs() -> Callable[..., tuple[np.ndarray, ...]]:
    """The random pair maker ``(rng, n, los_fraction) -> (origins, centres, shapes, lo, hi, los)``."""
    return _hull_box_pairs
