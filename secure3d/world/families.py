"""The protocol of random scenario families for campaigns.

A :class:`Family` makes variant ``i`` of a base scenario as a pure function of (base, seed, i):
:func:`variant_rng` gives variant ``i`` its own generator (``SeedSequence(seed).spawn(n)[i]``), so
variants can be drawn in any order, on any machine, without drawing the ones before. The families
shipped are registered in :mod:`secure3d.world.family_registry`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from secure3d.errors import ScenarioError
from secure3d.validation import is_int_in
from secure3d.world.spec import Scenario

__all__ = ["Family", "family_variants", "variant_rng"]


@dataclass(frozen=True)
class Family:
    """A random scenario family.

    Attributes
    ----------
    name : the name campaigns select it by (``secure3d campaign --kind NAME``).
    description : one line for ``--help`` and reports.
    prepare : ``prepare(base) -> prepared``: the expensive per-base work, done once.
    variant : ``variant(prepared, base, rng, i) -> Scenario``: variant ``i``, pure in its inputs.
    """

    name: str
    description: str
    prepare: Callable[[Scenario], Any]
    variant: Callable[[Any, Scenario, np.random.Generator, int], Scenario]


def variant_rng(seed: int, i: int) -> np.random.Generator:
    """Variant ``i``'s generator: ``SeedSequence(seed, spawn_key=(i,))``, i.e. ``spawn(n)[i]``."""
    for name, value in (("seed", seed), ("i", i)):
        if not is_int_in(value, 0, numpy=True):
            raise ScenarioError(f"{name}: must be a non-negative integer (got {value!r})")
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(int(i),)))


def family_variants(family: Family, base: Scenario, n: int, seed: int) -> list[Scenario]:
    """Variants ``0 .. n-1`` of ``base`` (``family.prepare`` once, then ``family.variant``)."""
    if not is_int_in(n, 0):
        raise ScenarioError(f"n: must be a non-negative integer (got {n!r})")
    prepared = family.prepare(base)
    return [family.variant(prepared, base, variant_rng(seed, i), i) for i in range(n)]
