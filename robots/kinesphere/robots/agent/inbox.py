"""What arrived for the control loop since its last step, bounded, e-stops first.

Zenoh callbacks (any thread) put decoded commands, undecodable payloads and databank answers
here; the control loop drains it once per step. Why not a plain queue:

* **E-stops go ahead of everything**, in a lane of their own, so a flood of commands from one
  sender cannot delay another's e-stop: the loop handles every e-stop of a step before any
  other command. The lane is bounded without losing a latch: when it is full, a newer e-stop
  of a sender waiting there takes the older one's place (one latches that sender), and
  another sender's e-stop becomes the lane's one :data:`OVERFLOW` e-stop, which latches the
  robot's overflow latch (``safety.py``).
* **Bounded**: the robot acts on the newest command of each sender, so a motion command
  replaces the one still waiting from the same ``(sender, session)`` (the replaced one is
  acknowledged ``superseded``). Commands that change more than the target (stop, e-stop
  release, lease actions, deadman release) are kept in order, at most :data:`PER_SENDER` per
  pair; at most :data:`MAX_PENDING` pairs wait at once (the least recently heard pair with
  only motion commands waiting goes first, so a flood from many senders cannot push out
  another's stop or release), and of undecodable payloads only the last is kept. Every bound
  is a count of messages the protocol itself bounds in bytes (64 KiB each).
"""

from __future__ import annotations

import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import msgspec

from kinesphere.errors import KinesphereError
from kinesphere.protocol import ANONYMOUS, OVERFLOW, Command, LeaseAction
from kinesphere.robots.agent.ordering import Received
from kinesphere.robots.agent.pacing import Wake
from kinesphere.robots.agent.resolver import PoseAnswer

MAX_ESTOPS = 64
"""E-stops kept per step (module text: past them, none is lost)."""
MAX_PENDING = 64
"""``(sender, session)`` pairs with commands waiting for the next step."""
PER_SENDER = 8
"""Commands one pair may have waiting."""

_MONO0 = time.monotonic_ns()
_WALL0 = time.time_ns()


def clocks() -> tuple[int, int]:
    """The robot's clocks now in ns: monotonic, and the wall clock derived from it."""
    mono = time.monotonic_ns()
    return mono, _WALL0 + (mono - _MONO0)


def received(cmd: Command, tick: int = 0) -> Received:
    """``cmd`` stamped with the robot's clocks now and the agent's step count ``tick``."""
    mono, wall = clocks()
    return Received(cmd, mono, wall, tick)


@dataclass(frozen=True)
class Resolved:
    """The databank's answer for a ticket."""

    ticket: int
    answer: PoseAnswer


class Drained(NamedTuple):
    """One step's worth: e-stops, then everything else in arrival order, then the commands
    replaced while they waited (to be acknowledged ``superseded``)."""

    estops: list[Received]
    items: list[Received | KinesphereError | Resolved]
    superseded: list[Received]


def replaceable(cmd: Command) -> bool:
    """A plain motion command: only its target matters once a newer one arrived."""
    return (cmd.deadman and not (cmd.estop or cmd.stop or cmd.release)
            and cmd.lease is LeaseAction.NONE)


class Inbox:
    """Thread-safe intake; :meth:`drain` empties it. Every put sets ``wake``, the control
    loop's signal to look now rather than at its next tick (``pacing.py``)."""

    def __init__(self, wake: Wake | None = None,
                 notify: Callable[[], None] | None = None) -> None:
        self.wake = Wake() if wake is None else wake
        self._notify = self.wake.set if notify is None else notify
        """Called after every put: sets ``wake`` (a fleet host's also notes the robot)."""
        self._lock = threading.Lock()
        self._arrivals = 0
        self._estops: deque[Received] = deque()
        self._pairs: OrderedDict[tuple[str, str], deque[tuple[int, Received]]] = OrderedDict()
        self._other: deque[tuple[int, KinesphereError | Resolved]] = deque(maxlen=16)
        self._bad: tuple[int, KinesphereError] | None = None
        self._superseded: deque[Received] = deque(maxlen=MAX_PENDING * PER_SENDER)

    def put(self, item: Received) -> None:
        cmd = item.cmd
        with self._lock:
            if cmd.estop:
                self._put_estop(item)
                self._notify()
                return
            self._arrivals += 1
            key = (cmd.sender, cmd.session)
            queue = self._pairs.get(key)
            if queue is None:
                queue = self._pairs[key] = deque()
                while len(self._pairs) > MAX_PENDING:
                    self._superseded.extend(r for _, r in self._evict(key))
            self._pairs.move_to_end(key)
            if queue and replaceable(cmd) and replaceable(queue[-1][1].cmd) \
                    and cmd.seq > queue[-1][1].cmd.seq:
                self._superseded.append(queue.pop()[1])
            elif len(queue) >= PER_SENDER:
                self._superseded.append(queue.popleft()[1])
            queue.append((self._arrivals, item))
        self._notify()

    def _put_estop(self, item: Received) -> None:
        """Into the e-stop lane, bounded without losing a latch (module text; under the
        lock)."""
        lane = self._estops
        if len(lane) >= MAX_ESTOPS - 1:
            who = item.cmd.sender or ANONYMOUS
            older = next((r for r in lane if (r.cmd.sender or ANONYMOUS) == who), None)
            if older is not None:
                lane.remove(older)  # this one latches its sender
            elif any(r.cmd.sender == OVERFLOW for r in lane):
                return  # the overflow e-stop waiting latches it
            else:
                item = item._replace(cmd=msgspec.structs.replace(item.cmd, sender=OVERFLOW))
        lane.append(item)

    def _evict(self, keep: tuple[str, str]) -> deque[tuple[int, Received]]:
        """Make room: the least recently heard pair waiting with motion commands only (they
        would be replaced by the next anyway), or, when every pair holds a stop, release or
        lease action, the least recently heard of all; never ``keep``, the pair arriving. So
        a flood from many senders cannot push out another's stop or e-stop release."""
        for key, queue in self._pairs.items():
            if key != keep and all(replaceable(r.cmd) for _, r in queue):
                return self._pairs.pop(key)
        key = next(k for k in self._pairs if k != keep)
        return self._pairs.pop(key)

    def put_bad(self, error: KinesphereError) -> None:
        """A payload that did not decode: only the last one waits (it names no sender)."""
        with self._lock:
            self._arrivals += 1
            self._bad = (self._arrivals, error)
        self._notify()

    def put_resolved(self, ticket: int, answer: PoseAnswer) -> None:
        with self._lock:
            self._arrivals += 1
            self._other.append((self._arrivals, Resolved(ticket, answer)))
        self._notify()

    def __len__(self) -> int:
        with self._lock:
            return (len(self._estops) + sum(len(q) for q in self._pairs.values())
                    + len(self._other) + (self._bad is not None))

    @property
    def waiting(self) -> bool:
        """Something is here for the next step (reading emptiness needs no lock: what
        arrives while this reads is seen at the next step, which its ``wake`` starts)."""
        return bool(self._estops or self._pairs or self._other or self._bad or self._superseded)

    def drain(self) -> Drained:
        if not self.waiting:
            return _EMPTY  # the common step: nothing new
        with self._lock:
            if len(self._pairs) == 1 and not (self._estops or self._other or self._bad
                                              or self._superseded):
                queue = self._pairs.popitem()[1]  # the usual step with news: one sender's
                return Drained([], [item for _, item in queue], [])  # commands, in order
            estops = list(self._estops)
            self._estops.clear()
            queued: list[tuple[int, Received | KinesphereError | Resolved]] = [
                entry for queue in self._pairs.values() for entry in queue]
            queued.extend(self._other)
            if self._bad is not None:
                queued.append(self._bad)
            self._pairs.clear()
            self._other.clear()
            self._bad = None
            superseded = list(self._superseded)
            self._superseded.clear()
        queued.sort(key=lambda entry: entry[0])
        return Drained(estops, [item for _, item in queued], superseded)


_EMPTY = Drained([], [], [])
