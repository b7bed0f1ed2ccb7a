"""An e-stop always latches, whatever the number of senders: past the senders' latches a
robot names, one more sender's e-stop holds the overflow latch, which no release clears and
a restart of the agent does; a fleet e-stop board full of e-stops in force keeps one more as
the overflow e-stop, so a robot started after every sender released theirs still comes up
latched. Real Zenoh, real agents."""

from __future__ import annotations

import time

import zenoh

from kinesphere import zconfig
from kinesphere.closing import Closable
from kinesphere.protocol import MAX_FLEET_ESTOPS, OVERFLOW, Ack, AckStage, Command, encode
from kinesphere.robots.agent.safety import MAX_LATCHES, OVERFLOW_WORDS
from support.agents import AckWatch, running_agent
from support.network import KEYS, Hub
from support.wait import WAIT_S, until

SESSION = "latches"


class Senders(Closable):
    """Many senders' e-stops and releases on one key (one publisher, never dropped)."""

    def __init__(self, session: zenoh.Session, key: str, count: int) -> None:
        self.pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                             express=True)
        assert zconfig.wait_matching(self.pub, WAIT_S), "the robot never subscribed"
        self.names = [f"op-{i}" for i in range(count)]

    def put(self, name: str, seq: int, estop: bool = False, release: bool = False) -> None:
        self.pub.put(encode(Command(seq=seq, sent_ns=time.time_ns(), deadman=not estop,
                                    ttl_ms=0, sender=name, session=SESSION, estop=estop,
                                    stop=estop, release=release)))

    def estop(self) -> None:
        for name in self.names:
            self.put(name, 1, estop=True)

    def release(self, names: list[str] | None = None) -> None:
        for name in self.names if names is None else names:
            self.put(name, 2, release=True)

    def close(self) -> None:
        zconfig.undeclare(self.pub)


def answered(acks: AckWatch, names: list[str], seq: int, stage: AckStage) -> None:
    """Each of ``names`` answered ``stage`` for its command ``seq``; one more sender's e-stop
    than a step's e-stop lane holds may be answered as the overflow e-stop's."""
    for name in names:
        ok = {name, OVERFLOW} if name == names[-1] else {name}

        def said(a: Ack, ok: set[str] = ok) -> bool:
            return a.seq == seq and a.stage == stage and a.sender in ok

        acks.wait(said, f"{stage} for {name}'s command {seq}")


def test_the_senders_past_the_named_latches_hold_one_that_only_a_restart_clears(
        hub: Hub) -> None:
    count = MAX_LATCHES + 2
    with (zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s,
          AckWatch(s, "lt-1") as acks):
        with (running_agent(hub.endpoint, "khepera", "lt-1") as (_, watch),
              Senders(s, KEYS.command("lt-1"), count) as ops):
            ops.estop()
            answered(acks, ops.names, 1, AckStage.ESTOPPED)  # every e-stop latched and said so
            st = watch.wait(lambda st: st.status == "estop" and OVERFLOW_WORDS in st.detail,
                            "latched by 16 named senders and the overflow latch")
            assert st.estop_by == "op-0"
            assert "only restarting its agent at the robot releases it" in st.detail

            ops.release()  # each named latch cleared by its own sender; the overflow stays
            st = watch.wait(lambda st: st.estop_by == OVERFLOW, "only the overflow latch left")
            assert st.status == "estop"
            ops.put(OVERFLOW, 2, release=True)  # not a sender anybody can be
            acks.wait(lambda a: a.sender == OVERFLOW and a.stage == AckStage.REJECTED,
                      "a release in the overflow latch's name refused")
        with running_agent(hub.endpoint, "khepera", "lt-1") as (_, watch):
            assert watch.states[0].status != "estop", "the restart cleared it"


def test_a_full_fleet_board_keeps_one_more_estop_in_force(hub: Hub) -> None:
    """As many senders' fleet e-stops as a board keeps, and one more: a robot started then
    comes up latched, named and overflow latches; after every sender released theirs, a robot
    started later still comes up latched by the overflow e-stop."""
    with (zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s,
          running_agent(hub.endpoint, "khepera", "lt-a") as (a, wa),
          AckWatch(s, "lt-a") as acks,
          Senders(s, KEYS.command("*"), MAX_FLEET_ESTOPS) as ops):
        ops.estop()
        answered(acks, ops.names, 1, AckStage.ESTOPPED)
        assert a.board is not None
        in_force = {r.sender for r in a.board.in_force()}
        assert in_force == {*ops.names[:MAX_FLEET_ESTOPS - 1], OVERFLOW}
        with running_agent(hub.endpoint, "khepera", "lt-b") as (b, wb):
            st = wb.states[0]
            assert st.status == "estop" and st.last_command_seq < 0, "latched before anything"
            assert OVERFLOW_WORDS in st.detail
            assert {r.sender for r in b.board.in_force()} == in_force  # type: ignore[union-attr]

        ops.release()
        until(lambda: {r.sender for r in a.board.in_force()} == {OVERFLOW},  # type: ignore[union-attr]
              WAIT_S, "every release heard, the overflow e-stop still in force")
        with running_agent(hub.endpoint, "khepera", "lt-c") as (_, wc):
            st = wc.states[0]
            assert st.status == "estop" and st.estop_by == OVERFLOW, st
        wa.wait(lambda st: st.estop_by == OVERFLOW, "lt-a: only the overflow latch left")
