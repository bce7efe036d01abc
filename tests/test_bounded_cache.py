"""The bounded least-recently-used cache behind the belief and voxel-world caches."""

from __future__ import annotations

import pytest

from secure3d._bounded_cache import BoundedCache
from secure3d.errors import ConfigError


def test_least_recently_used_go_first_by_entries_and_by_budget():
    cache = BoundedCache(3, 10, len)
    for key in "abc":
        cache.put(key, "xx")
    assert cache.get("a") == "xx"  # now the most recent: b goes first
    cache.put("d", "xx")
    assert list(cache.keys()) == ["c", "a", "d"] and cache.get("b") is None
    cache.put("e", "xxxxxx")  # 12 > 10 units with the others: the oldest goes, then it fits
    assert list(cache.keys()) == ["a", "d", "e"] and cache.held == 10
    cache.put("f", "x" * 11)  # over the budget alone: not kept, nothing dropped
    assert cache.get("f") is None and len(cache) == 3


@pytest.mark.parametrize(
    ("entries", "budget", "size", "word"),
    [(0, 1, len, "entries"), (True, 1, len, "entries"), (1, 0, len, "budget"), (1, 1, 3, "size")],
)
def test_bad_bounds_are_refused_by_name(entries, budget, size, word):
    with pytest.raises(ConfigError, match=word):
        BoundedCache(entries, budget, size)
