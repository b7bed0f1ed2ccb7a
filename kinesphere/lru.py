"""One bounded table, least recently used first out.

At most ``most`` entries and, given a ``size`` of each, at most ``max_bytes`` of them: what a
cache or a table remembered per name needs so that nothing a peer sends (senders and their
clocks, bodies, recorded sessions, nested solves) grows memory without bound. Not locked: its
owner serialises access.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class Lru(Generic[K, V]):
    """``key -> value``, the least recently used dropped first past ``most`` entries or
    ``max_bytes`` (``size(key, value)`` each; 0: no byte bound). An entry larger than
    ``max_bytes`` alone is not kept."""

    def __init__(self, most: int, max_bytes: int = 0,
                 size: Callable[[K, V], int] | None = None) -> None:
        if most < 1 or max_bytes < 0 or (max_bytes and size is None):
            raise ValueError(f"an Lru needs most >= 1 and a size for max_bytes, got most={most}, "
                             f"max_bytes={max_bytes}")
        self.most = most
        self.max_bytes = max_bytes
        self._size = size
        self._table: OrderedDict[K, tuple[V, int]] = OrderedDict()
        self.bytes = 0
        """What the entries kept cost, by ``size``."""

    def __len__(self) -> int:
        return len(self._table)

    def __contains__(self, key: object) -> bool:
        return key in self._table

    def get(self, key: K) -> V | None:
        """The value of ``key`` (now the most recently used), or None."""
        hit = self._table.get(key)
        if hit is None:
            return None
        self._table.move_to_end(key)
        return hit[0]

    def put(self, key: K, value: V) -> V:
        """Keep ``value`` under ``key`` as the most recently used, dropping the least recently
        used past the bounds; returns ``value``."""
        cost = self._size(key, value) if self._size is not None else 0
        old = self._table.pop(key, None)
        if old is not None:
            self.bytes -= old[1]
        if self.max_bytes and cost > self.max_bytes:
            return value
        self._table[key] = (value, cost)
        self.bytes += cost
        while len(self._table) > self.most or (self.max_bytes and self.bytes > self.max_bytes):
            _, (_, dropped) = self._table.popitem(last=False)
            self.bytes -= dropped
        return value
