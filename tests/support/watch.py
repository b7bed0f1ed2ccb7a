"""What a test hears on a key: every message put there, decoded, with waits on predicates.

The agents' state and ack streams and the commands a client puts are each a :class:`Watch`
of their own kind; a wait blocks on the subscriber's condition (no polling).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

import zenoh

from kinesphere import zconfig
from kinesphere.protocol import decode
from support.wait import WAIT_S

T = TypeVar("T")


class Watch(Generic[T]):
    """Every message put on ``key`` (may be a wildcard) as :meth:`decoded` makes it, in
    order of arrival."""

    def __init__(self, session: zenoh.Session, key: str, kind: type[T]) -> None:
        self.heard: list[T] = []
        self._kind = kind
        self._cond = threading.Condition()
        self._sub = session.declare_subscriber(key, self._on)

    def decoded(self, sample: zenoh.Sample) -> T:
        return decode(sample.payload, self._kind)

    def _on(self, sample: zenoh.Sample) -> None:
        item = self.decoded(sample)
        with self._cond:
            self.heard.append(item)
            self._cond.notify_all()

    def wait(self, pred: Callable[[T], bool], what: str, timeout: float = WAIT_S, *,
             from_latest: bool = False) -> T:
        """The first message heard so far or from now on that satisfies ``pred`` (with
        ``from_latest``: the latest one or one from now on)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            seen = max(0, len(self.heard) - 1) if from_latest else 0
            while True:
                for item in self.heard[seen:]:
                    if pred(item):
                        return item
                seen = len(self.heard)
                left = deadline - time.monotonic()
                if left <= 0 or not self._cond.wait(left):
                    raise AssertionError(f"timed out waiting for {what}; heard {seen}, the "
                                         f"last {self.heard[-3:]}")

    def close(self) -> None:
        zconfig.undeclare(self._sub)
