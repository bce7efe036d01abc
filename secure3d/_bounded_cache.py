"""A small thread-safe least-recently-used cache bounded by entries and by what the values hold.

Used where a process rebuilds the same large object from the same inputs: the robot's initial map
of a server claim (:func:`secure3d.world.attacks.belief_map`) and what the simulator builds from a
voxel world (:func:`secure3d.simulation.scene.by_voxel_content`). Values are shared between
callers: they copy them or only read them.
"""

from __future__ import annotations

import collections
import threading
from collections.abc import Callable, Hashable, Iterator

from secure3d.errors import ConfigError

__all__ = ["BoundedCache"]


class BoundedCache:
    """Values by key. Once more than ``entries`` values are held, or their ``size(value)`` add up
    to more than ``budget``, the least recently used go first; a value larger than ``budget`` on
    its own is not kept. ``entries`` and ``budget`` may be changed later (the next :meth:`put`
    keeps to them)."""

    def __init__(self, entries: int, budget: float, size: Callable[[object], float]) -> None:
        if isinstance(entries, bool) or not isinstance(entries, int) or entries < 1:
            raise ConfigError(f"BoundedCache: entries must be an integer >= 1, got {entries!r}")
        if not budget > 0:
            raise ConfigError(f"BoundedCache: budget must be > 0, got {budget!r}")
        if not callable(size):
            raise ConfigError(f"BoundedCache: size must be callable, got {size!r}")
        self.entries, self.budget, self._size = entries, budget, size
        self._items: collections.OrderedDict[Hashable, tuple[object, float]] = (
            collections.OrderedDict()
        )
        self._lock = threading.Lock()

    def get(self, key: Hashable) -> object | None:
        """The value kept for ``key`` (now the most recently used), or None."""
        with self._lock:
            hit = self._items.get(key)
            if hit is None:
                return None
            self._items.move_to_end(key)
            return hit[0]

    def put(self, key: Hashable, value: object) -> None:
        """Keep ``value`` for ``key`` unless it alone is over the budget; drop the least recently
        used until the rest fit."""
        size = self._size(value)
        if size > self.budget:
            return
        with self._lock:
            self._items[key] = (value, size)
            self._items.move_to_end(key)
            while len(self._items) > self.entries or self.held > self.budget:
                self._items.popitem(last=False)

    @property
    def held(self) -> float:
        """The sizes of the values kept, added up."""
        return sum(n for _, n in self._items.values())

    def keys(self) -> Iterator[Hashable]:
        """The keys kept, least recently used first."""
        return iter(list(self._items))

    def __len__(self) -> int:
        return len(self._items)
