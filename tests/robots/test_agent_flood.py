"""A robot agent process under a flood of malformed commands: it never moves, never stops
stepping or reporting, and stays bounded in memory.

The flood is mutations of a real drive command (bytes flipped, cut, spliced, deep nesting,
oversized integers) that the protocol refuses, put on the robot's command key right after an
operator stopped it. Measured: the robot's motion after the stop (must be none), the longest
gap in its state stream, its RSS before and after, and that it is still alive and obeys a
valid command afterwards.
"""

from __future__ import annotations

import random
import threading
import time

import pytest
import zenoh

from kinesphere import protocol as pr
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import KEYS
from kinesphere.procs import Supervisor
from kinesphere.zconfig import loopback_config, loopback_hub, undeclare
from support.soak import MIB, SCALE, FloodTally, mib, rss
from support.system import Observer, log_of
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

ROBOT = "flood-k"
MARK_SENDER = "flood-mark"
GROWTH_BOUND = 32 * MIB
"""What a flood of refused commands may add to an agent: Zenoh's receive buffers and the
allocator's arenas (measured: ~21 MiB, the same after 5,000 or 20,000); nothing it sends is
kept."""
PLATEAU = 8 * MIB
"""What the second half of the flood may add to the first: bounded means it stops growing."""
MAX_GAP_S = 0.5
"""Longest silence allowed in the 50 Hz state stream while the agent is flooded."""
BATCH = 1000
"""Malformed commands put between two marks (the flood never runs ahead of the agent by more:
RSS is read once the agent has read what was sent, however loaded the machine)."""


def drive(seq: int, stop: bool = False) -> pr.Command:
    """The operator's 50 Hz drive stream (``stop``: let go and stop)."""
    return pr.Command(seq=seq, sent_ns=time.time_ns(), deadman=not stop, stop=stop, ttl_ms=300,
                      drive=None if stop else pr.Drive("forward-middle", 0.5, forward=0.5),
                      sender="flood-test", session="s1")


def malformed(rng: random.Random, base: bytes) -> bytes:
    """A mutation of ``base`` that the protocol refuses (checked here, so none can move it)."""
    while True:
        b = bytearray(base)
        i = rng.randrange(len(b))
        op = rng.randrange(5)
        if op == 0:
            b[i] = rng.randrange(256)
        elif op == 1:
            del b[i:]
        elif op == 2:
            b[i:i + 1] = b"\x91" * rng.randint(100, 3000) + b"\xc0"
        elif op == 3:
            b[i:i + 1] = b"\xcf" + b"\xff" * 8
        else:
            b[i:i] = rng.randbytes(rng.randint(1, 64))
        try:
            pr.decode(bytes(b), pr.Command)
        except KinesphereError:
            return bytes(b)


class Marks:
    """A stop from another sender after each batch: the agent reads one subscriber's samples
    in order, so its ack says it has read (and refused) every malformed command put before."""

    def __init__(self, session: zenoh.Session, pub: zenoh.Publisher) -> None:
        self.pub = pub
        self.seq = 0
        self.acked = 0
        self._cond = threading.Condition()
        self._sub = session.declare_subscriber(KEYS.ack(ROBOT), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        ack = pr.decode(sample.payload.to_bytes(), pr.Ack)
        if ack.sender == MARK_SENDER:
            with self._cond:
                self.acked = max(self.acked, ack.seq)
                self._cond.notify_all()

    def read_up_to(self) -> None:
        """Put a mark and wait for the agent to ack it; again with a new mark every 0.5 s
        (Zenoh drops puts when its queues are full, and a flood fills them: a mark or its
        ack may be one of those; any later mark acked says the same)."""
        deadline = time.monotonic() + WAIT_S
        while True:
            self.seq += 1
            self.pub.put(pr.encode(pr.Command(seq=self.seq, sent_ns=time.time_ns(),
                                              deadman=False, stop=True, ttl_ms=0,
                                              sender=MARK_SENDER, session="marks")))
            with self._cond:
                if self._cond.wait_for(lambda: self.acked >= self.seq, 0.5):
                    return
            assert time.monotonic() < deadline, f"the agent acked no mark up to {self.seq}"

    def close(self) -> None:
        undeclare(self._sub)


class Stream:
    """Arrival times of the robot's states (to find the longest gap)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.times: list[float] = []
        self._sub = session.declare_subscriber(KEYS.state(ROBOT),
                                               lambda _s: self.times.append(time.monotonic()))

    def max_gap(self, since: float) -> float:
        t = [x for x in self.times if x >= since]
        return max((b - a for a, b in zip(t, t[1:], strict=False)), default=float("inf"))

    def close(self) -> None:
        undeclare(self._sub)



def pose(obs: Observer) -> list[float]:
    st = obs.states.last(ROBOT)
    assert st is not None
    return [*st.base_pose, *st.q]


def test_a_flood_of_malformed_commands_moves_nothing(sup: Supervisor) -> None:
    with loopback_hub() as (_hub, endpoint):
        agent = sup.spawn("agent", ["agent", "khepera", "--id", ROBOT, "--connect", endpoint])
        obs = Observer(loopback_config(endpoint))
        stream = Stream(obs.session)
        pub = obs.session.declare_publisher(KEYS.command(ROBOT))
        try:
            obs.wait_alive({ROBOT}, databank=False, sup=sup)
            # an operator drives it, then stops it: it comes to rest
            x0 = pose(obs)[0]
            seq = 0
            while pose(obs)[0] < x0 + 0.05:
                seq += 1
                pub.put(pr.encode(drive(seq)))
                obs.states.wait_for(lambda _s: False, 0.02)  # the operator's 50 Hz stream
                assert seq < 50 * WAIT_S, "the robot did not drive"
            seq += 1
            pub.put(pr.encode(drive(seq, stop=True)))
            rest = pose(obs)
            while True:
                assert obs.states.wait_fresh([ROBOT], time.time_ns() + 300_000_000, WAIT_S)
                now = pose(obs)
                if max(abs(a - b) for a, b in zip(now, rest, strict=True)) < 1e-4:
                    break
                rest = now
            # the flood
            rng = random.Random(3)
            base = pr.encode(drive(seq + 1))
            payloads = [malformed(rng, base) for _ in range(500)]
            tally = FloodTally("agent flood")
            marks = Marks(obs.session, pub)
            before, start = rss(agent.pid), time.monotonic()
            n = 5000 * SCALE
            mid = before
            for i in range(n):
                if i == n // 2:  # once the first half has been read and refused
                    marks.read_up_to()
                    mid = rss(agent.pid)
                pub.put(payloads[i % len(payloads)])
                tally.sent += 1
                if i % BATCH == BATCH - 1:  # not faster than the agent reads them
                    marks.read_up_to()
            marks.read_up_to()
            assert obs.states.wait_fresh([ROBOT], time.time_ns() + 300_000_000, WAIT_S)
            after, moved = rss(agent.pid), max(
                abs(a - b) for a, b in zip(pose(obs), rest, strict=True))
            gap = stream.max_gap(start)
            log_lines = len(log_of(agent).read_text(errors="replace").splitlines())
            tally.extra = {"motion after stop": f"{moved:.2e}", "longest state gap":
                           f"{gap * 1000:.0f} ms", "RSS before": mib(before),
                           "half-way": mib(mid), "after": mib(after),
                           "agent log lines": log_lines, "flood seconds":
                           f"{time.monotonic() - start:.1f}"}
            tally.report()
            assert agent.alive(), agent.tail()
            assert moved < 1e-3, tally.report()
            assert gap < MAX_GAP_S, tally.report()
            assert after - before < GROWTH_BOUND, tally.report()
            assert after - mid < PLATEAU, tally.report()
            # and it still obeys a valid command
            x1 = pose(obs)[0]
            until(lambda: pub.put(pr.encode(drive(seq + 10**6))) or pose(obs)[0] > x1 + 0.02,
                  WAIT_S, "the robot to drive again after the flood")
            marks.close()
        finally:
            undeclare(pub)
            stream.close()
            obs.close()
