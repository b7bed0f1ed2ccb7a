"""A robot agent process under a flood of malformed commands: it never moves, never stops
stepping or reporting, and stays bounded in memory.

The flood is mutations of a real drive command (bytes flipped, cut, spliced, deep nesting,
oversized integers) that the protocol refuses, put on the robot's command key right after an
operator stopped it, in rounds of the same size. Measured: the robot's motion after the stop
(must be none), the longest silence in its state stream that the agent's own waiting for a
CPU does not explain, its RSS after each round, and that it is still alive and obeys a valid
command afterwards.

Neither measure depends on how loaded the machine is. A silence is taken on the agent's own
clock (the states' stamps) minus the time its threads waited in the kernel's run queue meanwhile
(``/proc/<pid>/task/*/schedstat``): a loop blocked by decoding stays silent while it runs and
fails; a loop the scheduler did not run is explained. Bounded memory is a round that adds
nothing: a table growing with what is sent grows in every round, noise (Zenoh's buffers, the
allocator's arenas, larger when the agent falls behind) in some.
"""

from __future__ import annotations

import random
import threading
import time
from pathlib import Path

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
allocator's arenas (measured: ~22 MiB, about the same after 10,000 or 200,000); nothing it
sends is kept."""
PLATEAU = 8 * MIB
"""What the least growing of the later rounds may add: bounded means it stops growing."""
ROUNDS = 4
"""Rounds of the flood, each of the same malformed commands (the first fills the buffers)."""
MAX_SILENCE_S = 0.5
"""Longest silence allowed in the 50 Hz state stream while the agent is flooded, beyond the
time its threads waited for a CPU."""
SAMPLE_S = 0.01
"""How often the agent's run-queue waits are sampled."""
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


class Waits:
    """The agent's threads' run-queue waits (ns), sampled on the wall clock every SAMPLE_S."""

    def __init__(self, pid: int) -> None:
        self.tasks = Path(f"/proc/{pid}/task")
        self.samples: list[tuple[int, dict[str, int]]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="flood-waits", daemon=True)
        self._thread.start()

    def _read(self) -> dict[str, int]:
        out = {}
        for task in self.tasks.iterdir():
            try:
                out[task.name] = int((task / "schedstat").read_text().split()[1])
            except (OSError, IndexError, ValueError):  # a thread that ended meanwhile
                continue
        return out

    def _run(self) -> None:
        while not self._stop.is_set():
            self.samples.append((time.time_ns(), self._read()))
            self._stop.wait(SAMPLE_S)

    def waited(self, a_ns: int, b_ns: int) -> float:
        """Seconds the agent's most delayed thread waited for a CPU in a window holding
        ``a_ns`` to ``b_ns`` (from the last sample before to the first after: the window may
        be wider, never narrower)."""
        before = [w for t, w in self.samples if t <= a_ns]
        after = [w for t, w in self.samples if t >= b_ns]
        if not before or not after:
            return 0.0
        w0, w1 = before[-1], after[0]
        return max((w1[k] - w0[k] for k in w1.keys() & w0.keys()), default=0) / 1e9

    def close(self) -> None:
        self._stop.set()
        self._thread.join()


class Stream:
    """The robot's states (seq, stamp on the agent's clock), to find its longest silence."""

    def __init__(self, session: zenoh.Session) -> None:
        self.states: list[tuple[int, int]] = []
        self._sub = session.declare_subscriber(KEYS.state(ROBOT), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        st = pr.decode(sample.payload.to_bytes(), pr.RobotState)
        self.states.append((st.seq, st.stamp_ns))

    def silence(self, since_ns: int, waits: Waits) -> tuple[float, float, int]:
        """From the last state before ``since_ns`` on: the longest gap between two states
        published one after the other (seq + 1: nothing was published in between) less what
        the agent waited for a CPU in it, that gap (seconds), and how many states were
        published but not received (a gap around those proves no silence)."""
        got = sorted(set(self.states))
        first = max([i for i, (_, t) in enumerate(got) if t < since_ns], default=0)
        got = got[first:]
        gaps = [((b - a) / 1e9 - waits.waited(a, b), (b - a) / 1e9)
                for (i, a), (j, b) in zip(got, got[1:], strict=False) if j == i + 1]
        lost = sum(j - i - 1 for (i, _), (j, _) in zip(got, got[1:], strict=False))
        return (*max(gaps, default=(float("inf"), float("inf"))), lost)

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
        waits = Waits(agent.pid)
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
            sizes = [rss(agent.pid)]
            start, start_ns = time.monotonic(), time.time_ns()
            n = 2500 * SCALE
            for _ in range(ROUNDS):
                for i in range(n):
                    pub.put(payloads[i % len(payloads)])
                    tally.sent += 1
                    if i % BATCH == BATCH - 1:  # not faster than the agent reads them
                        marks.read_up_to()
                marks.read_up_to()  # the round has been read and refused
                sizes.append(rss(agent.pid))
            assert obs.states.wait_fresh([ROBOT], time.time_ns() + 300_000_000, WAIT_S)
            moved = max(abs(a - b) for a, b in zip(pose(obs), rest, strict=True))
            silence, gap, lost = stream.silence(start_ns, waits)
            growth = [b - a for a, b in zip(sizes, sizes[1:], strict=False)]
            log_lines = len(log_of(agent).read_text(errors="replace").splitlines())
            tally.extra = {"motion after stop": f"{moved:.2e}", "longest silence":
                           f"{silence * 1000:.0f} ms (of a {gap * 1000:.0f} ms gap)",
                           "states not received": lost,
                           "RSS before": mib(sizes[0]), "after each round":
                           ", ".join(mib(x) for x in sizes[1:]),
                           "agent log lines": log_lines, "flood seconds":
                           f"{time.monotonic() - start:.1f}"}
            tally.report()
            assert agent.alive(), agent.tail()
            assert moved < 1e-3, tally.report()
            assert silence < MAX_SILENCE_S, tally.report()
            assert sizes[-1] - sizes[0] < GROWTH_BOUND, tally.report()
            assert min(growth[1:]) < PLATEAU, tally.report()
            # and it still obeys a valid command
            x1 = pose(obs)[0]
            until(lambda: pub.put(pr.encode(drive(seq + 10**6))) or pose(obs)[0] > x1 + 0.02,
                  WAIT_S, "the robot to drive again after the flood")
            marks.close()
        finally:
            waits.close()
            undeclare(pub)
            stream.close()
            obs.close()
