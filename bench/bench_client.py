"""What an operator's client waits for: its put of a command -> the robots' acks back to it.

Agents at 500 Hz run in this process on their own session; the client is a ``RobotLink`` on
the hub's session, with the real databank behind both (cached poses). Measured, through the
client's own code (``Sequencer``, ``RobotLink.put``, its ack subscriber):

- one robot: put of a pose command -> the ``accepted`` ack, and -> the ``moving`` ack;
- every robot: ``estop_all`` -> every robot's ``estopped`` ack (what ``kinesphere estop``
  waits for), for 1 and 4 robots.

The baseline, interleaved one by one in the same run: a bare round trip between the same two
sessions (put -> subscriber callback -> put back -> callback) of a payload the size of the
command, the least any acknowledged exchange can cost on this machine.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import numpy as np
import zenoh

from bench.bench_agent import databank, pct, two_parts
from kinesphere import zconfig
from kinesphere.clients.link import RobotLink, Sequencer
from kinesphere.keyexpr import Keys
from kinesphere.protocol import AckStage, encode
from kinesphere.robots.agent.runtime import Agent, AgentOptions

KEYS = Keys()
COMMANDS = 200
ESTOPS = 40
FANOUT = (1, 4)


class Echo:
    """A bare round trip from session ``a`` to ``b`` and back, timed at ``a``."""

    def __init__(self, a: zenoh.Session, b: zenoh.Session, payload: bytes) -> None:
        self.payload = payload
        self._got = threading.Event()
        self._back = b.declare_publisher("bench/echo/back", express=True)
        self._there = b.declare_subscriber("bench/echo/there",
                                           lambda s: self._back.put(s.payload))
        self._home = a.declare_subscriber("bench/echo/back", lambda s: self._got.set())
        self._pub = a.declare_publisher("bench/echo/there", express=True)
        zconfig.wait_matching(self._pub)
        zconfig.wait_matching(self._back)

    def once(self) -> float:
        """Microseconds of one round trip."""
        self._got.clear()
        t0 = time.monotonic()
        self._pub.put(self.payload)
        self._got.wait(1.0)
        return (time.monotonic() - t0) * 1e6

    def close(self) -> None:
        zconfig.undeclare(self._pub, self._home, self._there, self._back)


def _ack_at(link: RobotLink, robot: str, seq: int, stage: AckStage, timeout: float = 2.0
            ) -> float | None:
    """When (monotonic) the client holds ``robot``'s ack of ``seq`` at ``stage``."""
    def find(lk: RobotLink) -> float | None:
        for a in lk.answers(seq).get(robot, []):
            if a.ack.seq == seq and a.ack.stage == stage:
                return a.at
        return None

    link.wait_for(lambda lk: find(lk) is not None, timeout)
    return find(link)


def _pause() -> None:
    """25-35 ms between commands: under the robots' ack rate limit (100 per sender and second),
    and never phase-locked to the 500 Hz loop."""
    time.sleep(0.025 + 0.01 * np.random.random())


def command_acks(link: RobotLink, seq: Sequencer, agent: Agent, echo: Echo) -> None:
    parts = two_parts(agent)
    key = [KEYS.command(agent.robot_id)]
    assert link.wait_subscribers(key, 10) == []
    accepted, moving, floor = [], [], []
    for i in range(COMMANDS + 2):
        floor.append(echo.once())
        _pause()
        cmd = seq.command([parts[i % 2]], deadman=True)
        t0 = time.monotonic()
        link.put(key, cmd)
        got = _ack_at(link, agent.robot_id, cmd.seq, AckStage.MOVING)
        acc = _ack_at(link, agent.robot_id, cmd.seq, AckStage.ACCEPTED, 0.0)
        if i >= 2 and got is not None and acc is not None:  # the first two fill the cache
            accepted.append((acc - t0) * 1e6)
            moving.append((got - t0) * 1e6)
        _pause()
    lost = COMMANDS - len(moving)
    _row("put -> accepted ack", accepted, floor[2:])
    _row("put -> moving ack", moving, floor[2:])
    print(f"    ({lost} of {COMMANDS} commands without both acks within 2 s)")


def estop_acks(link: RobotLink, seq: Sequencer, agents: list[Agent], echo: Echo) -> None:
    ids = [a.robot_id for a in agents]
    assert link.wait_for(lambda lk: set(lk.robots()) >= set(ids), 10)
    every, floor, lost = [], [], 0
    for _ in range(ESTOPS):
        floor.append(echo.once())
        _pause()
        t0 = time.monotonic()
        cmd = link.estop_all(seq)
        found = [_ack_at(link, rid, cmd.seq, AckStage.ESTOPPED) for rid in ids]
        if all(t is not None for t in found):
            every.append((max(t for t in found if t is not None) - t0) * 1e6)
        else:
            lost += 1
        release = seq.release()
        link.put([KEYS.command("*")], release)
        for rid in ids:
            _ack_at(link, rid, release.seq, AckStage.RELEASED)
        _pause()
    _row(f"estop -> all {len(ids)} estopped acks", every, floor)
    print(f"    ({lost} of {ESTOPS} e-stops without every ack within 2 s)")


def _row(what: str, values: list[float], floor: list[float]) -> None:
    if not values:
        print(f"  {what:<30} no samples")
        return
    v50, v99, f50, f99 = pct(values, 50), pct(values, 99), pct(floor, 50), pct(floor, 99)
    print(f"  {what:<30} p50 {v50:8.1f}us  p99 {v99:8.1f}us   round-trip floor p50 "
          f"{f50:6.1f}us  p99 {f99:7.1f}us   ratio p50 {v50 / f50:5.2f}x  p99 "
          f"{v99 / f99:5.2f}x", flush=True)


def _with_agents(n: int, endpoint: str, body: Callable[[list[Agent], zenoh.Session], None]
                 ) -> None:
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        agents = [Agent("baxter", f"bench-client-{n}-{i}", s, AgentOptions(speed=1.0)).start()
                  for i in range(n)]
        try:
            body(agents, s)
        finally:
            for a in agents:
                a.close()


def main() -> None:
    logging.getLogger("kinesphere.robots.agent").setLevel(logging.ERROR)
    print(f"client round trips on loopback (Baxter agents at 500 Hz in this process, the real "
          f"databank); {COMMANDS} commands, {ESTOPS} e-stops per robot count, each beside a "
          "bare round trip between the same sessions:")
    with zconfig.loopback_hub() as (hub, endpoint), databank(endpoint, hub):
        link = RobotLink(hub, KEYS, sender="bench-operator")
        seq = link.sequencer(ttl_ms=0)
        try:
            for n in FANOUT:
                def measure(agents: list[Agent], s: zenoh.Session, n: int = n) -> None:
                    probe = encode(seq.command(two_parts(agents[0])[:1], deadman=True))
                    echo = Echo(hub, s, probe)
                    try:
                        if n == 1:
                            command_acks(link, seq, agents[0], echo)
                        estop_acks(link, seq, agents, echo)
                    finally:
                        echo.close()
                _with_agents(n, endpoint, measure)
        finally:
            link.close()


if __name__ == "__main__":
    main()
