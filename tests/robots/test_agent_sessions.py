"""Sessions and identities at the robot: old commands expire whichever session they belong
to, a session's order cannot be pushed to the end, the sender is the one its key names, an
e-stop is released only by whoever latched it, and a client told ``stale`` starts afresh.

Before: after SIGSTOP/SIGCONT a command of a session the robot had not heard (1.5 s old)
moved Baxter 0.352 rad; ``seq = 2^63-1`` with a victim's (sender, session) made every later
motion command of that session ``stale`` and the client never started a new session; bob
released alice's e-stop, and so did a command with no sender. Rules are checked on the
ordering and safety logic, then over real Zenoh on loopback with in-process agents, and the
freeze with a real agent process.
"""

from __future__ import annotations

import time
from functools import partial

import msgspec
import zenoh

from kinesphere import zconfig
from kinesphere.clients.link import RobotLink
from kinesphere.closing import Closable
from kinesphere.keyexpr import Keys
from kinesphere.protocol import (
    ANONYMOUS,
    MAX_INT,
    Ack,
    Command,
    Drive,
    LeaseAction,
    SpatialCommand,
    encode,
)
from kinesphere.robots.agent.ordering import REBASE_S, SEQ_WINDOW, Ordering, Received
from kinesphere.robots.agent.safety import Safety, Verdict
from support.agents import (
    AckWatch,
    DatabankProcess,
    Part,
    held_agent,
    running_agent,
)
from support.network import KEYS, Hub
from support.wait import WAIT_S

S = 1_000_000_000
T0 = 1_800_000_000 * S
"""A sender's clock at the first command (ns since the epoch)."""
OFFSET = 37 * S
"""How far the robot's clock runs ahead of the sender's (unsynchronised clocks)."""
DRIVE = Drive(direction="forward-middle", speed=0.5)


def cmd(seq: int, sent_ns: int, session: str = "a", clock: str = "host-1", sender: str = "ann",
        ttl_ms: int = 300, **kw: object) -> Command:
    return msgspec.structs.replace(Command(seq=seq, sent_ns=sent_ns, deadman=True, ttl_ms=ttl_ms,
                                           drive=DRIVE, sender=sender, session=session,
                                           clock=clock), **kw)


def _first_from(sender: str, ack: Ack) -> bool:
    return ack.sender == sender and ack.seq == 0


def at(o: Ordering, c: Command, mono_ns: int, delay_ns: int = 1_000_000) -> str:
    """What the robot says to ``c``, received ``delay_ns`` after it was sent (robot clocks:
    monotonic ``mono_ns``, wall = the sender's + OFFSET), processed at once."""
    err = o.admit(Received(c, mono_ns, c.sent_ns + OFFSET + delay_ns), mono_ns)
    return "ok" if err is None else err.code


# --- expiry across sessions ------------------------------------------------------------------


def test_a_new_sessions_backlog_is_timed_by_its_clocks_offset() -> None:
    o = Ordering()
    assert at(o, cmd(0, T0), 0) == "ok"  # the robot learns host-1's offset
    # ten seconds on, the robot was frozen: a new session's first command (a one-shot `send`)
    # arrives 1.5 s after it was sent
    assert at(o, cmd(0, T0 + 10 * S, session="b"), 11 * S, delay_ns=1_500_000_000) == "expired"
    assert at(o, cmd(1, T0 + 12 * S, session="b"), 12 * S) == "ok"  # fresh ones go through
    # another host of the same operator has a clock of its own
    assert at(o, cmd(0, T0 + 13 * S, session="c", clock="host-2"), 13 * S,
              delay_ns=900_000_000) == "ok"


def test_a_clock_first_heard_during_a_stall_counts_the_stall() -> None:
    o = Ordering()
    o.stalled(10 * S, 11_500_000_000)  # the control loop did not run for 1.5 s
    assert at(o, cmd(0, T0, session="1", clock="new"), 11 * S) == "expired"
    assert at(o, cmd(0, T0, session="2", clock="newer"), 11_600_000_000) == "expired"  # after
    assert at(o, cmd(0, T0, session="3", clock="later"), 13 * S) == "ok"  # well after it
    assert at(o, cmd(0, T0, session="4", clock="ttl", ttl_ms=2000), 11 * S) == "ok"  # long ttl


def test_a_clock_that_steps_back_is_taken_once_it_stays_late() -> None:
    o = Ordering()
    assert at(o, cmd(0, T0), 0) == "ok"
    seen = []
    for k in range(1, 100):  # 30 Hz: the sender's clock stepped back by 5 s
        seen.append(at(o, cmd(k, T0 + k * S // 30 - 5 * S), k * S // 30,
                        delay_ns=5 * S + 1_000_000))
    first_ok = seen.index("ok")
    assert set(seen[:first_ok]) == {"expired"} and set(seen[first_ok:]) == {"ok"}
    assert REBASE_S * 30 - 1 <= first_ok <= REBASE_S * 30 + 1


def test_seq_cannot_be_pushed_to_the_end_of_the_numbers() -> None:
    o = Ordering()
    assert at(o, cmd(5, T0), 0) == "ok"
    assert at(o, cmd(MAX_INT, T0 + 1), 1) == "stale"  # forged: refused, not remembered
    assert at(o, cmd(6, T0 + 2), 2) == "ok"
    assert at(o, cmd(6 + SEQ_WINDOW + 1, T0 + 3), 3) == "stale"
    assert at(o, cmd(6 + SEQ_WINDOW, T0 + 4), 4) == "ok"  # inside the window: taken
    assert at(o, cmd(SEQ_WINDOW + 1, T0 + 5, session="fresh"), 5) == "stale"
    assert at(o, cmd(MAX_INT, T0 + 6, estop=True, stop=True, deadman=False), 6) == "ok"
    assert at(o, cmd(7 + SEQ_WINDOW, T0 + 7), 7) == "ok"  # the e-stop was not remembered


# --- e-stop latches ----------------------------------------------------------------------------


def test_an_estop_is_released_only_by_whoever_latched_it() -> None:
    s = Safety()

    c = partial(cmd, 0, T0)

    assert s.on_command(c(sender="alice", estop=True), 0.0) is Verdict.ESTOP
    assert s.on_command(c(sender="bob", release=True), 0.1) is Verdict.LATCHED
    assert s.on_command(c(sender="", release=True), 0.2) is Verdict.LATCHED
    assert s.on_command(c(sender="bob", estop=True), 0.3) is Verdict.ESTOP
    assert s.latches == ["alice", "bob"] and s.estop_by == "alice"
    assert s.on_command(c(sender="alice", release=True), 0.4) is Verdict.LATCHED  # bob's holds
    assert s.on_command(c(sender="bob", release=True), 0.5) is Verdict.RELEASE
    assert s.on_command(c(sender="", estop=True), 0.6) is Verdict.ESTOP  # nobody's latch:
    assert s.on_command(c(sender="", release=True), 0.7) is Verdict.LATCHED
    assert s.on_command(c(sender="carol", release=True), 0.8) is Verdict.RELEASE  # a named one


def test_a_release_clears_only_an_estop_sent_before_it() -> None:
    """Before: a late copy of one round's release (copies are sent until every robot answers;
    its session had ended) reached two robots just after the next round's e-stop and cleared
    it, while ``kinesphere estop`` reported all eight latched (the e-stop flood, 200 rounds
    under load)."""
    s = Safety()
    estop = cmd(0, T0 + 2 * S, session="round-2", sender="op", estop=True)
    assert s.on_command(estop, 0.0) is Verdict.ESTOP
    late = cmd(2, T0 + S, session="round-1", sender="op", release=True)
    assert s.on_command(late, 0.1) is Verdict.LATCHED and s.predates(late) == "op"
    assert s.latches == ["op"]
    again = cmd(0, T0 + 2 * S, session="round-2-release", sender="op", release=True)
    assert not s.predates(again) and s.on_command(again, 0.2) is Verdict.RELEASE
    # nobody's latch: a release sent before it leaves it too
    assert s.on_command(cmd(0, T0 + 5 * S, sender="", estop=True), 0.3) is Verdict.ESTOP
    early = cmd(1, T0 + 4 * S, sender="bob", release=True)
    assert s.predates(early) == ANONYMOUS  # the refusal names that latch, not bob's own
    assert s.on_command(early, 0.4) is Verdict.LATCHED
    assert s.on_command(cmd(2, T0 + 6 * S, sender="bob", release=True), 0.5) is Verdict.RELEASE


# --- over the wire -----------------------------------------------------------------------------


class Signed(Closable):
    """Puts commands on a robot's key signed with ``signer`` (``""``: the plain key)."""

    def __init__(self, session: zenoh.Session, robot_id: str, signer: str) -> None:
        key = KEYS.command(robot_id)
        self.pub = session.declare_publisher(Keys.signed(key, signer) if signer else key,
                                             congestion_control=zenoh.CongestionControl.BLOCK)
        assert zconfig.wait_matching(self.pub, WAIT_S), "the robot never subscribed"
        self.seq = 0

    def send(self, sender: str, **kw: object) -> int:
        self.seq += 1
        cmd = Command(seq=self.seq, sent_ns=time.time_ns(), deadman=True, ttl_ms=0,
                      sender=sender, session="s", clock="c")
        self.pub.put(encode(msgspec.structs.replace(cmd, **kw)))
        return self.seq

    def close(self) -> None:
        zconfig.undeclare(self.pub)


def test_the_robot_takes_the_sender_from_the_key(hub: Hub) -> None:
    session, endpoint = hub
    with (AckWatch(session, "signed") as acks,
          running_agent(endpoint, "khepera", robot_id="signed", speed=1.0) as (_, watch),
          Signed(session, "signed", "alice") as alice, Signed(session, "signed", "bob") as bob,
          Signed(session, "signed", "") as plain):
        seq = alice.send("", lease=LeaseAction.ACQUIRE)  # no name in the payload: the key's
        acks.of("alice", seq, "leased")
        watch.after(seq, lambda s: s.lease_holder == "alice", "alice holds the lease")
        bob.seq = 100
        forged = bob.send("alice", lease=LeaseAction.TAKE)  # bob's key, alice's name
        seq = alice.send("alice", estop=True, stop=True, deadman=False)
        acks.of("alice", seq, "estopped")
        assert acks.stages("alice", forged) == [] and acks.stages("bob", forged) == []
        assert watch.after(seq, lambda s: True, "a state").lease_holder == "alice"
        seq = bob.send("bob", release=True)
        assert acks.of("bob", seq, "rejected").code == "estopped"
        seq = plain.send("", release=True)  # no sender anywhere: releases nothing
        assert "name its sender" in acks.of("", seq, "rejected").detail
        watch.after(seq, lambda s: s.status == "estop" and s.estop_by == "alice", "latched")
        seq = alice.send("alice", release=True)
        acks.of("alice", seq, "released")


def test_a_late_copy_of_a_release_leaves_the_next_estop_latched(hub: Hub) -> None:
    session, endpoint = hub
    with (AckWatch(session, "late-copy") as acks,
          running_agent(endpoint, "khepera", robot_id="late-copy", speed=1.0) as (_, watch),
          Signed(session, "late-copy", "") as op):
        before = time.time_ns()  # when the last round's release was sent
        seq = op.send("op", estop=True, stop=True, deadman=False)
        acks.of("op", seq, "estopped")
        seq = op.send("op", release=True, sent_ns=before, session="ended")
        refused = acks.of("op", seq, "rejected")
        assert refused.code == "estopped", refused
        assert "this release was sent before op's latest e-stop" in refused.detail
        heard = time.time_ns()
        watch.wait(lambda s: s.stamp_ns > heard and s.status == "estop" and s.estop_by == "op",
                   "still latched after the late copy")
        seq = op.send("op", release=True)
        acks.of("op", seq, "released")


def test_a_client_told_stale_starts_a_fresh_session(hub: Hub) -> None:
    session, endpoint = hub
    with running_agent(endpoint, "khepera", robot_id="victim", speed=1.0), \
            zconfig.session(config=zconfig.loopback_config(endpoint)) as mine:
        link = RobotLink(mine, KEYS, sender="vic")
        forger = Signed(session, "victim", "vic")  # open mode: no router vouches for names
        try:
            seq = link.sequencer(0)
            key = [KEYS.command("victim")]
            assert link.wait_subscribers(key, WAIT_S) == []

            def answered(n: int, stage: str) -> bool:
                return link.wait_for(lambda lk: any(
                    a.ack.seq == n and a.ack.stage == stage
                    for a in lk.answers(n).get("victim", [])), WAIT_S)

            first = seq.lease(LeaseAction.ACQUIRE)
            link.put(key, first)
            assert answered(first.seq, "leased")
            # pushed to the end of the numbers: refused and not remembered (the link, which
            # sees the refusal of a command in its session, moves on to a fresh one anyway)
            forger.seq = MAX_INT - 1
            forged = forger.send("vic", session=link.session_id, lease=LeaseAction.ACQUIRE)
            assert answered(forged, "rejected")
            nxt = seq.lease(LeaseAction.ACQUIRE)
            link.put(key, nxt)
            assert answered(nxt.seq, "leased")
            # pushed within the window: the next command is stale, and the link starts afresh
            forger.seq = nxt.seq + SEQ_WINDOW - 2
            forged = forger.send("vic", session=nxt.session, lease=LeaseAction.ACQUIRE)
            assert answered(forged, "leased")  # the robot took it: the session is pushed
            stale = seq.lease(LeaseAction.ACQUIRE)
            link.put(key, stale)
            assert answered(stale.seq, "rejected")
            assert link.wait_for(lambda lk: lk.session_id != stale.session, WAIT_S)
            again = seq.lease(LeaseAction.ACQUIRE)
            assert again.session == link.session_id and again.seq > stale.seq
            link.put(key, again)
            assert answered(again.seq, "leased")
        finally:
            forger.close()
            link.close()


def test_a_new_sessions_command_queued_while_the_robot_was_frozen_never_runs(
    hub: Hub, databank: DatabankProcess
) -> None:
    """The operator was heard before (one session); the robot is frozen; a new session (the
    next `send`) and a sender never heard each put a command; 1.5 s later the robot thaws:
    both are dropped as expired and nothing moves."""
    session, _ = hub
    pub = session.declare_publisher(Keys.signed(KEYS.command("thawed"), "ann"),
                                    congestion_control=zenoh.CongestionControl.BLOCK)
    stranger = session.declare_publisher(Keys.signed(KEYS.command("thawed"), "zed"),
                                         congestion_control=zenoh.CongestionControl.BLOCK)
    sent = 0

    def session_one(part: Part) -> int:
        """Session "one" takes the robot to the first target."""
        nonlocal sent
        if not sent:
            assert zconfig.wait_matching(pub, WAIT_S), "the robot never subscribed"
            assert zconfig.wait_matching(stranger, WAIT_S), "the robot never subscribed"
        sent += 1
        pub.put(encode(cmd(sent, time.time_ns(), session="one", clock="ann-host", ttl_ms=300,
                           drive=None, parts=[SpatialCommand(*part)])))
        return sent

    try:
        with held_agent(hub, databank, "thawed", session_one) as robot:
            robot.freeze()
            there = [SpatialCommand(*robot.there)]
            pub.put(encode(cmd(0, time.time_ns(), session="two", clock="ann-host", ttl_ms=1000,
                               drive=None, parts=there)))
            stranger.put(encode(cmd(0, time.time_ns(), sender="zed", session="z",
                                    clock="zed-host", ttl_ms=1000, drive=None, parts=there)))
            time.sleep(1.5)  # the freeze outlasts both ttls (the test's subject, not a wait)
            seen = robot.thaw()
            for who in ("ann", "zed"):
                ack = robot.acks.wait(partial(_first_from, who),
                                      f"the verdict on {who}'s frozen command")
                assert ack.stage == "rejected" and ack.code == "expired", ack
            after, moved = robot.moved_after(seen)
            assert moved < 5e-3, f"the robot moved {moved:.4f} rad after SIGCONT"
            assert after.dropped >= 2
    finally:
        zconfig.undeclare(pub, stranger)
