"""An agent under abuse and faults: frozen and thawed, flooded, fed garbage, told to forget
a sender. It must drop what is too old, keep e-stops first, stay bounded, and say so.

Real Zenoh on loopback, the real databank, a real agent process for the freeze (SIGSTOP and
SIGCONT), in-process agents where the test reads the agent's own counters.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from functools import partial

import msgspec
import numpy as np
import psutil
import pytest

from kinesphere import zconfig
from kinesphere.protocol import MAX_INT, Ack, Command, SpatialCommand, encode
from kinesphere.robots.agent import acks as ack_rules
from kinesphere.robots.agent.inbox import MAX_PENDING, PER_SENDER
from kinesphere.robots.agent.ordering import MAX_SENDERS
from support.agents import (
    AckWatch,
    CommandSender,
    DatabankProcess,
    far,
    held_agent,
    running_agent,
)
from support.network import KEYS, Hub
from support.wait import WAIT_S

pytestmark = pytest.mark.processes


def _verdict_on(seq: int, ack: Ack) -> bool:
    return ack.seq == seq and ack.stage in ("rejected", "superseded", "accepted")


def test_commands_queued_while_the_agent_was_frozen_never_run(
    hub: Hub, databank: DatabankProcess
) -> None:
    """SIGSTOP a real agent while an operator streams at 30 Hz (ttl 300 ms), switch to another
    target while it is frozen, stop streaming, SIGCONT: nothing moves, the commands are
    dropped as expired and counted."""
    session, _ = hub
    with (CommandSender(session, "frozen", sender="ann", client_session="a") as op,
          held_agent(hub, databank, "frozen", partial(op.send, ttl_ms=300)) as robot):
        goal = databank.query("baxter", SpatialCommand(*robot.there)).joints
        index = [robot.state.joint_names.index(j) for j in goal]
        before = np.array(robot.state.q)
        gap = np.abs(before[index] - np.array(list(goal.values()))).max()
        assert gap > 0.3, "the second target is a real motion away"
        robot.freeze()
        frozen = []
        for _ in range(30):  # a client streaming at 30 Hz
            time.sleep(1 / 30)
            frozen.append(op.send(robot.there, ttl_ms=300))
        time.sleep(1.0)  # the operator stopped: a freeze that outlasts the ttl
        seen = robot.thaw()
        for seq in frozen[-3:]:
            ack = robot.acks.wait(partial(_verdict_on, seq), "a verdict on a frozen command")
            assert ack.stage != "accepted", ack
        assert any(a.code == "expired" for a in robot.acks.acks if a.seq in frozen)
        after, moved = robot.moved_after(seen)
        assert moved < 5e-3, f"the robot moved {moved:.4f} rad after SIGCONT (of {gap:.2f})"
        assert after.dropped >= 1 and after.last_command_seq < frozen[0]


def test_a_flood_cannot_delay_an_estop_and_every_table_stays_bounded(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    cat = databank.catalogue("youbot")
    parts = [far(cat, k) for k in range(4)]
    with (AckWatch(session, "flooded") as acks,
          running_agent(endpoint, "youbot", robot_id="flooded", speed=1.0) as (agent, watch),
          CommandSender(session, "flooded", sender="panic", client_session="p") as estop):
        agent.resolver.cache_bytes = 50_000
        rss = psutil.Process(os.getpid()).memory_info().rss
        flood = session.declare_publisher(KEYS.command("flooded"))
        assert zconfig.wait_matching(flood, WAIT_S), "the robot never subscribed"
        n = 20_000
        done = threading.Event()

        def flooding() -> None:
            for i in range(n):  # 3 000 senders with names at the protocol's cap, distinct keys
                flood.put(encode(Command(
                    seq=i + 1, sent_ns=time.time_ns(), deadman=True, ttl_ms=1000,
                    parts=[SpatialCommand(*parts[i % 4][:3], 1.0 + (i % 997) / 1000)],
                    sender=f"{i % 3000:064d}", session="s" * 64)))
            done.set()

        thread = threading.Thread(target=flooding)
        thread.start()
        acks.wait(lambda a: a.sender.startswith("0"), "the flood reaches the robot")
        seq = estop.send(estop=True)
        acks.of("panic", seq, "estopped")
        watch.wait(lambda s: s.status == "estop" and s.estop_by == "panic", "latched")
        thread.join()
        done.wait(WAIT_S)
        watch.wait(lambda s: len(agent.inbox) == 0, "the flood drained")
        seq = estop.send(release=True)
        acks.of("panic", seq, "released")
        grown = psutil.Process(os.getpid()).memory_info().rss - rss
        conduct = agent.conduct
        assert list(conduct.estop_lag) and max(conduct.estop_lag) <= 1, conduct.estop_lag
        assert conduct.acks.refused["estopped"] > 0, "the e-stop landed mid-flood"
        assert len(conduct.ordering) <= MAX_SENDERS
        assert len(conduct.acks.limiter) <= ack_rules.MAX_BUCKETS
        assert len(agent.inbox) <= MAX_PENDING * PER_SENDER
        assert agent.resolver.cached_bytes <= 50_000 and len(agent.resolver) > 0
        assert grown < 64 * 2**20, f"RSS grew {grown / 2**20:.0f} MiB"
        flooded_acks = [a for a in acks.acks if a.sender.startswith("0")]
        stamps = [a.stamp_ns for a in flooded_acks]
        span = (max(stamps) - min(stamps)) / 1e9  # when the robot decided, first to last
        assert len(flooded_acks) <= ack_rules.TOTAL_BURST + ack_rules.TOTAL_RATE * span + 1
        assert len(flooded_acks) < n / 4, "acks are bounded in rate, not one per command"
        zconfig.undeclare(flood)


def test_garbage_is_malformed_in_one_log_line_and_a_forged_clock_silences_nobody(
    hub: Hub, databank: DatabankProcess, caplog: pytest.LogCaptureFixture,
    capfd: pytest.CaptureFixture[str],
) -> None:
    session, endpoint = hub
    cat = databank.catalogue("youbot")
    deep = b"\x91" * 100_000 + b"\xc0"
    oversized = msgspec.msgpack.encode({"type": "command", "pad": "x" * 70_000})
    with (AckWatch(session, "garbage") as acks,
          caplog.at_level(logging.WARNING, logger="kinesphere.robots.agent"),
          running_agent(endpoint, "youbot", robot_id="garbage", speed=2.0) as (agent, watch),
          CommandSender(session, "garbage", sender="victim") as op):
        for _ in range(100):
            for payload in (deep, oversized, b"\x93not a command"):
                op.raw(payload)
        watch.wait(lambda s: s.status == "error" and "malformed" in s.detail, "reported")
        forged = op.send(far(cat, 0), seq=MAX_INT, sent_ns=MAX_INT)
        assert acks.of("victim", forged, "rejected").code == "malformed"
        seq = op.send(far(cat, 1), seq=1)
        acks.of("victim", seq, "accepted", "the victim's next command is obeyed")
    refusals = [r for r in caplog.records if "command refused" in r.getMessage()]
    assert 1 <= len(refusals) <= 3, [r.getMessage() for r in refusals]
    assert "Traceback" not in capfd.readouterr().err
