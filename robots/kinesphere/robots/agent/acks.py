"""What the robot tells each sender about its commands (``{p}/robot/{id}/ack``), at a bounded rate.

Two small parts:

* :class:`Acks` tracks the command whose target the robot is following, so it can say
  ``moving`` once its first step ran and, when the motion ends, ``reached``, ``clamped`` or
  ``blocked``; a different target (or sender) replacing it is ``superseded``. A stream of
  commands for one target from one ``(sender, session)`` is one motion: each gets
  ``accepted``, the motion a single ``moving`` and the last command the final stage.
* :class:`AckLimiter` bounds the publication rate with token buckets, per sender and in all, so
  a flooding sender cannot make the robot flood the network (or starve others' acks). Acks of
  e-stops and releases are never held back. Held-back acks are counted, not queued.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from typing import NamedTuple

from kinesphere.lru import Lru
from kinesphere.protocol import (
    MAX_TEXT,
    Ack,
    AckStage,
    BodyWord,
    Command,
    Pose,
    Substitution,
    encode,
)

log = logging.getLogger(__name__)

SENDER_RATE = 100.0
"""Acks per second to one sender (a gamepad streams 30 commands a second)."""
SENDER_BURST = 50.0
TOTAL_RATE = 1000.0
"""Acks per second from one robot in all."""
TOTAL_BURST = 200.0
MAX_BUCKETS = 256
"""Senders whose buckets are remembered (least recently acknowledged forgotten first)."""
URGENT = frozenset({AckStage.ESTOPPED, AckStage.RELEASED})
"""Acks never held back by the rate limit."""
SAME_MOMENT_S = 0.05
"""How far apart (s, the host's clock) the due times of one streamed command's copies may lie
(the network's jitter between them): a command for the same target due later than that is
another motion (``Acks.follow``)."""


class AckLimiter:
    """Token buckets: one per sender (bounded table) and one for the robot."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._buckets: Lru[Hashable, list[float]] = Lru(MAX_BUCKETS)
        self._total = [TOTAL_BURST, clock()]
        self.held = 0
        """Acks not published because a bucket was empty."""

    def __len__(self) -> int:
        return len(self._buckets)

    @staticmethod
    def _take(bucket: list[float], now: float, rate: float, burst: float) -> bool:
        bucket[0] = min(burst, bucket[0] + (now - bucket[1]) * rate)
        bucket[1] = now
        if bucket[0] < 1.0:
            return False
        bucket[0] -= 1.0
        return True

    def allow(self, sender: Hashable) -> bool:
        now = self._clock()
        bucket = self._buckets.get(sender)
        if bucket is None:
            bucket = self._buckets.put(sender, [SENDER_BURST, now])
        ok = self._take(bucket, now, SENDER_RATE, SENDER_BURST) and self._take(
            self._total, now, TOTAL_RATE, TOTAL_BURST)
        if not ok:
            self.held += 1
        return ok


class Meaning(NamedTuple):
    """What a command meant on this body, told in its acks: the parts served with another
    direction, the body words it answers with another name (``right_arm``: the only arm), and
    how far from the request the pose points (the answer's measured angle)."""

    substitutions: tuple[Substitution, ...] = ()
    words: tuple[BodyWord, ...] = ()
    measured_angle: float | None = None

    @classmethod
    def of(cls, pose: Pose) -> Meaning:
        return cls(tuple(pose.substitutions), tuple(pose.words), pose.measured_angle)


PLAIN = Meaning()
"""A command that meant what it said."""


class Pending(NamedTuple):
    """An ack decided during a step, published at the step's flush."""

    cmd: Command
    stage: AckStage
    code: str
    detail: str
    meaning: Meaning
    lease_holder: str
    stamp_ns: int
    late_ms: int = 0


class Due(NamedTuple):
    """A moment by two clocks: the robot's (its control loop's time, which a loop that falls
    behind real time slows) and the host's monotonic one (the senders' seconds go by it)."""

    robot: float
    wall: float


@dataclass
class Motion:
    """The command being followed and what the robot said about it."""

    cmd: Command
    target: Hashable
    meaning: Meaning = PLAIN
    moved: bool = False
    due: Due | None = None
    """When the motion is to arrive (a command's ``arrive_ms``), else None."""
    eta: Due = Due(0.0, 0.0)
    """When a timed motion under way would arrive, as last planned."""


class Acks:
    """One robot's acknowledgements: the followed motion, the rate limit, the publisher.

    ``publish`` puts encoded bytes (None until the agent declared its publisher: nothing is
    sent); ``publish_urgent`` puts e-stop and release acks on the highest priority, never
    dropped (:class:`UrgentOut`; the same as ``publish`` when unset);
    ``lease_holder`` says who holds the robot's lease, for every ack.
    """

    def __init__(self, robot_id: str, lease_holder: Callable[[], str]) -> None:
        self.robot_id = robot_id
        self.lease_holder = lease_holder
        self.publish: Callable[[bytes], None] | None = None
        self.publish_urgent: Callable[[bytes], None] | None = None
        self.limiter = AckLimiter()
        self.motion: Motion | None = None
        self.sent = 0
        self.refused: Counter[str] = Counter()
        """Commands rejected, by error code (whether or not the ack was held back)."""
        self.late: Callable[[Motion, bool], int] = lambda motion, planned: 0
        """How late a motion with a ``due`` time arrives, in the sender's ms: as planned at
        its first step (``planned``), else as it went (set by the agent)."""
        self._pending: list[Pending] = []

    def send(self, cmd: Command, stage: AckStage, detail: str = "", *, code: str = "",
             meaning: Meaning = PLAIN, late_ms: int = 0) -> None:
        """Tell ``cmd``'s sender ``stage``, within the rate limit (e-stops: always), at the
        next :meth:`flush`, stamped now (when the robot decided, not when it published)."""
        if stage is AckStage.REJECTED:
            self.refused[code] += 1
        if self.publish is None or not (stage in URGENT or self.limiter.allow(cmd.sender)):
            return
        self._pending.append(Pending(cmd, stage, code, detail, meaning,
                                     self.lease_holder(), time.time_ns(), late_ms))

    def flush(self) -> None:
        """Publish what :meth:`send` queued. The control loop flushes once the step's
        setpoints went to the body, so encoding and putting acks never delays a command's
        first step (the rate limit already bounds how many wait)."""
        pending, self._pending = self._pending, []
        for p in pending:
            publish = (self.publish_urgent if p.stage in URGENT else None) or self.publish
            if publish is None:
                return
            try:
                publish(make_ack(self.robot_id, p.cmd, p.stage, code=p.code, detail=p.detail,
                                 meaning=p.meaning, lease_holder=p.lease_holder,
                                 stamp_ns=p.stamp_ns, late_ms=p.late_ms))
                self.sent += 1
            except Exception as exc:  # session closing or congested: the loop goes on
                log.debug("ack not published: %s", exc)

    @property
    def pending(self) -> bool:
        """Acks decided and not yet published (:meth:`flush`)."""
        return bool(self._pending)

    @property
    def substitutions(self) -> list[Substitution]:
        """Those of the followed motion (``RobotState.substitutions``)."""
        return list(self.motion.meaning.substitutions) if self.motion is not None else []

    def follow(self, cmd: Command, target: Hashable, meaning: Meaning = PLAIN,
               due: Due | None = None) -> None:
        """``cmd`` is now followed (to arrive at ``due``); another motion it replaced is
        ``superseded``, saying how late it was. A stream of one target keeps the arrival time
        of its first command (its copies count down to the same moment); the same target due
        at a later moment (a score's next keyframe holding the pose) is a new motion, so the
        lateness of the one before is told to the command it belongs to."""
        old = self.motion
        if old is not None and old.target == target and (
                old.cmd.sender, old.cmd.session) == (cmd.sender, cmd.session) and _same_moment(
                due, old.due):
            old.cmd = cmd  # the same stream: the last command gets the final stage
            old.meaning = meaning
            return
        self.motion = Motion(cmd, target, meaning, due=due)
        if old is not None:
            self.send(old.cmd, AckStage.SUPERSEDED,
                      f"command {cmd.seq} from {cmd.sender or '?'} replaced it",
                      late_ms=self._late(old, False))

    def _late(self, m: Motion, planned: bool) -> int:
        return self.late(m, planned) if m.due is not None else 0

    def stepped(self) -> Command | None:
        """The followed command, the first time a step's setpoint went toward it
        (acknowledged ``moving``, saying how late it will arrive if it has a time)."""
        m = self.motion
        if m is None or m.moved:
            return None
        m.moved = True
        late = self._late(m, True)
        self.send(m.cmd, AckStage.MOVING, f"arrives {late} ms late" if late else "",
                  late_ms=late)
        return m.cmd

    def end(self, stage: AckStage, detail: str = "") -> None:
        """The followed motion is over (reached, halted, replaced): its last command gets
        ``stage``."""
        m, self.motion = self.motion, None
        if m is not None:
            self.send(m.cmd, stage, detail, meaning=m.meaning, late_ms=self._late(m, False))


def _same_moment(due: Due | None, followed: Due | None) -> bool:
    """Whether a command due at ``due`` counts down to the ``followed`` motion's moment: it
    sets no time of its own, or one within :data:`SAME_MOMENT_S` of that motion's."""
    return due is None or (followed is not None and due.wall - followed.wall <= SAME_MOMENT_S)


class UrgentOut:
    """E-stop and release acks, put by a thread of their own on a publisher that never drops
    (congestion control BLOCK): a loaded process's transmit queue drops a DROP message after
    a millisecond, and a client that never hears the e-stop acknowledged must report the
    robot unconfirmed. The control loop only appends here, so a congested link never stalls
    it. Bounded: at most :data:`URGENT_KEPT` acks wait (the oldest go first)."""

    def __init__(self, put: Callable[[bytes], None], name: str) -> None:
        self._put = put
        self._queue: deque[bytes] = deque(maxlen=URGENT_KEPT)
        self._wake = threading.Condition()
        self._closing = False
        self._thread = threading.Thread(target=self._run, name=f"urgent-acks-{name}",
                                        daemon=True)
        self._thread.start()

    def __call__(self, payload: bytes) -> None:
        with self._wake:
            self._queue.append(payload)
            self._wake.notify()

    def _run(self) -> None:
        while True:
            with self._wake:
                while not self._queue and not self._closing:
                    self._wake.wait()
                if not self._queue:
                    return
                payload = self._queue.popleft()
            try:
                self._put(payload)
            except Exception as exc:  # session closing: nothing more gets out
                log.debug("urgent ack not published: %s", exc)

    def close(self, timeout: float = 1.0) -> None:
        """Put what waits (within ``timeout``), then stop."""
        with self._wake:
            self._closing = True
            self._wake.notify()
        self._thread.join(timeout)


URGENT_KEPT = 1024
"""E-stop and release acks waiting for the network at most (64 KiB each at worst)."""


def make_ack(robot_id: str, cmd: Command, stage: AckStage, *, code: str = "", detail: str = "",
             meaning: Meaning = PLAIN, lease_holder: str = "",
             stamp_ns: int | None = None, late_ms: int = 0) -> bytes:
    """The encoded Ack for ``cmd`` (detail cut to the protocol's 1024 characters), stamped
    ``stamp_ns`` (default: now)."""
    return encode(Ack(
        robot_id=robot_id, sender=cmd.sender, session=cmd.session, seq=cmd.seq, stage=stage,
        code=code, detail=detail[:MAX_TEXT],
        stamp_ns=time.time_ns() if stamp_ns is None else stamp_ns,
        substitutions=list(meaning.substitutions), words=list(meaning.words),
        measured_angle=meaning.measured_angle, lease_holder=lease_holder, late_ms=late_ms))
