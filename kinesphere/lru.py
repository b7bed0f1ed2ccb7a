"""One bounded table, least recently used first out.

At most ``most`` entries and, given a ``size`` of each, at most ``max_bytes`` of them: what a
cache or a table remembered per name needs so that nothing a peer sends (senders and their
clocks, bodies, recorded sessions, nested solves, replies, rate-limit buckets) grows memory
without bound. Not locked: its owner serialises writes. :meth:`get` alone may run beside a
writer without the lock (each step on the table is atomic under the GIL), so a hot path can
read a cache without taking one.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable, Iterator
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class Lru(Generic[K, V]):
    """``key -> value``, the least recently used dropped first past ``most`` entries or
    ``max_bytes`` (``size(key, value)`` each; 0: no byte bound). An entry costing more than
    ``largest`` (default ``max_bytes``) is not kept.

    ``size`` is asked again when an entry leaves, so it must not change while the entry is
    kept; in return the table holds nothing per entry but its dict slot, and an owner's
    measured charge per entry (the databank's ``ENTRY_BYTES``) stays true.
    """

    def __init__(self, most: int, max_bytes: int = 0,
                 size: Callable[[K, V], int] | None = None, *, largest: int = 0) -> None:
        if (most < 1 or max_bytes < 0 or (max_bytes and size is None) or largest < 0
                or (largest and (size is None or (max_bytes and largest > max_bytes)))):
            raise ValueError(f"an Lru needs most >= 1, a size for max_bytes or largest, and "
                             f"largest <= max_bytes, got most={most}, max_bytes={max_bytes}, "
                             f"largest={largest}")
        self.most = most
        self.max_bytes = max_bytes
        self.largest = largest
        """0: ``max_bytes``."""
        self._size = size
        self._table: OrderedDict[K, V] = OrderedDict()
        self.peek: Callable[[K], V | None] = self._table.get
        """``peek(key)``: the value of ``key``, or None, leaving the order as it is (the
        table's own look-up: a memo read on a hot path costs what a dict's does, and its
        entries then leave in the order they came)."""
        self.bytes = 0
        """What the entries kept cost, by ``size``."""

    def __len__(self) -> int:
        return len(self._table)

    def __contains__(self, key: object) -> bool:
        return key in self._table

    def __iter__(self) -> Iterator[K]:
        """The keys, least recently used first."""
        return iter(self._table)

    def items(self) -> Iterator[tuple[K, V]]:
        """``(key, value)`` pairs, least recently used first."""
        return iter(self._table.items())

    def get(self, key: K) -> V | None:
        """The value of ``key`` (now the most recently used), or None."""
        hit = self._table.get(key)
        if hit is not None:
            try:
                self._table.move_to_end(key)
            except KeyError:  # a writer dropped it meanwhile (a lock-free reader): still an answer
                pass
        return hit

    def put(self, key: K, value: V) -> V:
        """Keep ``value`` under ``key`` as the most recently used, dropping the least recently
        used past the bounds; returns ``value``."""
        size = self._size
        self.pop(key)
        if size is None:
            self._table[key] = value
            while len(self._table) > self.most:
                self._table.popitem(last=False)
            return value
        cost = size(key, value)
        limit = self.largest or self.max_bytes
        if limit and cost > limit:
            return value
        self._table[key] = value
        self.bytes += cost
        while len(self._table) > self.most or (self.max_bytes and self.bytes > self.max_bytes):
            self.bytes -= size(*self._table.popitem(last=False))
        return value

    def pop(self, key: K) -> V | None:
        """Forget ``key``; its value, or None."""
        old = self._table.pop(key, None)
        if old is not None and self._size is not None:
            self.bytes -= self._size(key, old)
        return old

    def clear(self) -> None:
        self._table.clear()
        self.bytes = 0
