"""What a test hears from another thread: items kept in order of arrival, with waits on
predicates (a wait blocks on a condition: no polling).

:class:`Heard` is the list and its waits, fed by whatever hears (a subscriber, a reader of a
process's output); :class:`Watch` feeds one from a Zenoh subscription. The agents' state and
ack streams, the commands a client puts, a ROS topic and the ROS 2 peer's events are each
one of these.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

import zenoh

from kinesphere import zconfig
from kinesphere.closing import Closable
from kinesphere.protocol import decode
from support.wait import WAIT_S

T = TypeVar("T")


class Heard(Generic[T]):
    """Items :meth:`add` ed from any thread, in order, with waits on predicates."""

    def __init__(self) -> None:
        self.heard: list[T] = []
        self._cond = threading.Condition()

    def add(self, item: T) -> None:
        with self._cond:
            self.heard.append(item)
            self._cond.notify_all()

    def explain(self) -> str:
        """What a timed-out wait adds to its message."""
        return f"heard {len(self.heard)}, the last {self.heard[-3:]}"

    def wait(self, pred: Callable[[T], bool], what: str, timeout: float = WAIT_S, *,
             start: int = 0) -> T:
        """The first item from index ``start`` on (negative: counted from the latest), heard
        so far or from now on, that satisfies ``pred``; ``pred`` may raise to fail at once."""
        deadline = time.monotonic() + timeout
        with self._cond:
            seen = max(0, len(self.heard) + start) if start < 0 else start
            while True:
                for item in self.heard[seen:]:
                    if pred(item):
                        return item
                seen = len(self.heard)
                left = deadline - time.monotonic()
                if left <= 0 or not self._cond.wait(left):
                    raise AssertionError(f"no {what} within {timeout:g} s; {self.explain()}")


class Watch(Heard[T], Closable):
    """Every message put on ``key`` (may be a wildcard) as :meth:`decoded` makes it; used as
    ``with``, its subscriber is undeclared even when the block fails, so a failing test leaves
    nothing declared on the shared hub."""

    def __init__(self, session: zenoh.Session, key: str, kind: type[T]) -> None:
        super().__init__()
        self._kind = kind
        self._sub = session.declare_subscriber(key, self._on)

    def decoded(self, sample: zenoh.Sample) -> T:
        return decode(sample.payload, self._kind)

    def _on(self, sample: zenoh.Sample) -> None:
        self.add(self.decoded(sample))

    def close(self) -> None:
        zconfig.undeclare(self._sub)
