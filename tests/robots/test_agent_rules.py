"""The agent's command rules without the network: ordering and expiry, the lease, the inbox,
the ack rate limit. Fast and deterministic; the wire tests show the same rules end to end."""

from __future__ import annotations

import itertools
from functools import partial

import msgspec

from kinesphere.errors import KinesphereError
from kinesphere.protocol import OVERFLOW, Command, Drive, LeaseAction, SpatialCommand
from kinesphere.robots.agent import acks
from kinesphere.robots.agent.acks import AckLimiter
from kinesphere.robots.agent.inbox import MAX_ESTOPS, MAX_PENDING, PER_SENDER, Inbox, Resolved
from kinesphere.robots.agent.lease import LEASE_TIMEOUT_S, Lease
from kinesphere.robots.agent.ordering import MAX_CLOCK_AHEAD_S, Ordering, Received
from kinesphere.robots.agent.safety import MAX_LATCHES, OVERFLOW_WORDS, Safety, Verdict

MS = 1_000_000
PART = SpatialCommand("limb_11", "distal_11", "left-high", 2.0)


def cmd(seq: int, sender: str = "op", session: str = "s1", sent_ms: int = 1000,
        **kw: object) -> Command:
    return msgspec.structs.replace(Command(seq=seq, sent_ns=sent_ms * MS, deadman=True, ttl_ms=300,
                                           sender=sender, session=session, parts=[PART]), **kw)


def at(c: Command, recv_ms: int, offset_ms: int = 0) -> Received:
    """``c`` received at ``recv_ms`` on the robot's clocks (wall = mono + offset)."""
    return Received(c, recv_ms * MS, (recv_ms + offset_ms) * MS)


def commands(items: list[Received | KinesphereError | Resolved]) -> list[Received]:
    """Drained items, each a command received (the tests put nothing else)."""
    assert all(isinstance(r, Received) for r in items), items
    return [r for r in items if isinstance(r, Received)]


def codes(o: Ordering, items: list[Received], now_ms: int | None = None) -> list[str]:
    out = []
    for r in items:
        err = o.admit(r, (now_ms if now_ms is not None else r.mono_ns // MS) * MS)
        out.append(err.code if err is not None else "ok")
    return out


def test_ordering_is_per_sender_and_session_and_a_fresh_session_resets_it() -> None:
    o = Ordering()
    assert codes(o, [at(cmd(5), 1000), at(cmd(4), 1001), at(cmd(5), 1002)]) == \
        ["ok", "stale", "stale"]
    assert codes(o, [at(cmd(1, session="s2"), 1003)]) == ["ok"], "a new session starts over"
    assert codes(o, [at(cmd(1, sender="other"), 1004)]) == ["ok"], "senders are apart"
    assert codes(o, [at(cmd(3, estop=True), 1005), at(cmd(2, stop=True), 1006),
                     at(cmd(1, deadman=False), 1007)]) == ["ok"] * 3, "stops are never stale"
    assert o.dropped == 2


def test_version_one_senders_without_a_session_may_restart() -> None:
    o = Ordering()
    old = partial(cmd, session="", sent_ms=1000)
    assert codes(o, [at(old(9), 1000), at(old(8), 1001)]) == ["ok", "stale"]
    assert codes(o, [at(cmd(1, session="", sent_ms=2000), 2000)]) == ["ok"], "restarted"


def test_a_far_future_sent_ns_cannot_silence_a_sender() -> None:
    o = Ordering()
    attack = cmd(2**63 - 1, session="", sent_ms=10**12)
    err = o.admit(at(attack, 1000), 1000 * MS)
    assert err is not None and err.code == "malformed" and "ahead" in err.message
    assert codes(o, [at(cmd(1, session="", sent_ms=1000), 1001)]) == ["ok"]
    ahead_ms = int(MAX_CLOCK_AHEAD_S * 1000) + 1
    assert codes(o, [at(cmd(5, estop=True, sent_ms=1000 + ahead_ms), 1002)]) == ["ok"], \
        "an e-stop is obeyed whatever its clock says"
    assert codes(o, [at(cmd(2, session="", sent_ms=1001), 1003)]) == ["ok"], \
        "and does not become the sender's newest"


def test_commands_expire_by_receipt_age_and_by_arriving_late() -> None:
    o = Ordering()
    # clocks 5 s apart: only differences count
    stream = [at(cmd(i, sent_ms=1000 + 33 * i), 6000 + 33 * i + 2) for i in range(1, 6)]
    assert codes(o, stream) == ["ok"] * 5
    assert codes(o, [at(cmd(6, sent_ms=1200), 6200)], now_ms=6200 + 301) == ["expired"], \
        "waited in the robot longer than its ttl"
    frozen = [at(cmd(7 + i, sent_ms=1300 + 33 * i), 9500) for i in range(30)]
    assert codes(o, frozen) == ["expired"] * 30, \
        "queued while the robot was frozen, delivered when it ran again: all too late"
    assert codes(o, [at(cmd(37, sent_ms=4450), 9501)]) == ["ok"], "a fresh one is obeyed"
    assert codes(o, [at(cmd(40, ttl_ms=0, sent_ms=1400), 9600)]) == ["ok"], "ttl 0: no expiry"
    assert codes(o, [at(cmd(41, ttl_ms=0, parts=[], drive=Drive(forward=0.5), sent_ms=1400),
                        9601)]) == ["expired"], "a drive always has a ttl"
    assert codes(o, [at(cmd(42, stop=True, sent_ms=1400), 9602)]) == ["ok"]
    assert o.dropped == 32


def test_the_sender_table_is_bounded() -> None:
    o = Ordering(max_senders=50)
    for i in range(500):
        o.admit(at(cmd(1, sender=f"s{i:061d}", session="x" * 64), 1000), 1000 * MS)
    assert len(o) == 50


def test_lease_rules() -> None:
    lease = Lease()
    a = partial(cmd, sender="a", session="1")
    b = partial(cmd, sender="b", session="2")
    assert lease.check(a(1, deadman=False), 0.0).allowed and lease.holder == "", \
        "letting go neither needs nor takes a free lease"
    assert lease.check(a(2), 0.1).holder == "a"
    v = lease.check(b(1), 0.2)
    assert not v.allowed and v.holder == "a"
    assert not lease.check(b(2, deadman=False), 0.25).allowed, "b cannot make a hold"
    assert not lease.check(b(3, lease=LeaseAction.ACQUIRE, parts=[]), 0.3).allowed
    for c in (b(4, estop=True), b(4, stop=True), b(4, release=True)):
        assert lease.check(c, 0.4).allowed, c
    v = lease.check(b(5, lease=LeaseAction.TAKE), 0.5)
    assert v.allowed and v.holder == "b" and v.taken_from == "a"
    assert not lease.check(a(3), 0.6).allowed
    assert lease.check(b(6, lease=LeaseAction.RELEASE, parts=[]), 0.7).holder == ""
    assert lease.check(a(4), 0.8).holder == "a"
    assert lease.expire(0.8 + LEASE_TIMEOUT_S + 0.01) == "a" and lease.holder == ""
    assert lease.check(b(7), 5.0).holder == "b"
    assert lease.check(cmd(9, sender="", session=""), 5.1).holder == "b", "anonymous waits"
    assert lease.expire(5.0 + LEASE_TIMEOUT_S + 0.01) == "b"
    old_client = lease.check(cmd(10, sender="v1", session=""), 9.0)
    assert old_client.allowed and lease.holder == "", "a client without session takes no lease"
    assert lease.check(cmd(11, sender="v1", session="", lease=LeaseAction.ACQUIRE), 9.1).holder \
        == "v1", "unless it asks"


def test_inbox_puts_estops_first_coalesces_motion_and_stays_bounded() -> None:
    box = Inbox()
    seq = itertools.count(1)
    for _ in range(100):
        box.put(at(cmd(next(seq), sender="flood"), 1))
    box.put(at(cmd(next(seq), sender="flood", stop=True), 1))
    box.put(at(cmd(next(seq), sender="other", estop=True), 1))
    box.put(at(cmd(next(seq), sender="flood"), 1))
    d = box.drain()
    assert [r.cmd.sender for r in d.estops] == ["other"]
    assert [(r.cmd.seq, r.cmd.stop) for r in commands(d.items)] == [
        (100, False), (101, True), (103, False)]
    assert len(d.superseded) == 99 and box.drain().items == []
    for i in range(10 * MAX_PENDING):
        for _ in range(2):
            box.put(at(cmd(next(seq), sender=f"s{i}", stop=True), 1))
    for _ in range(5 * PER_SENDER):
        box.put(at(cmd(next(seq), sender="s0", release=True), 1))
    assert len(box) <= MAX_PENDING * PER_SENDER


def test_a_flood_from_many_senders_cannot_push_out_a_stop_or_a_release() -> None:
    """The pair evicted to make room is one with motion commands only: a waiting stop and
    e-stop release survive any number of flooding senders (their motion is superseded)."""
    box = Inbox()
    seq = itertools.count(1)
    box.put(at(cmd(next(seq), sender="panic", release=True), 1))
    box.put(at(cmd(next(seq), sender="calm", stop=True), 1))
    for i in range(4 * MAX_PENDING):
        box.put(at(cmd(next(seq), sender=f"flood{i}"), 1))
    d = box.drain()
    kept = [r.cmd.sender for r in commands(d.items)]
    assert kept[:2] == ["panic", "calm"] and len(kept) == MAX_PENDING
    assert len(d.superseded) == 4 * MAX_PENDING - (MAX_PENDING - 2)
    assert all(r.cmd.sender.startswith("flood") for r in d.superseded)
    for i in range(2 * MAX_PENDING):  # every pair holds a stop: the least recently heard goes
        box.put(at(cmd(next(seq), sender=f"stop{i}", stop=True), 1))
    d = box.drain()
    assert [r.cmd.sender for r in commands(d.items)] == [f"stop{i}" for i in range(MAX_PENDING,
                                                                         2 * MAX_PENDING)]


def test_ack_rate_is_bounded_per_sender_and_in_all() -> None:
    now = [0.0]
    limiter = AckLimiter(clock=lambda: now[0])
    sent = sum(limiter.allow("flood") for _ in range(10_000))
    assert sent == acks.SENDER_BURST
    now[0] += 0.1
    sent = sum(limiter.allow("flood") for _ in range(10_000))
    assert sent == round(0.1 * acks.SENDER_RATE), "0.1 s later: 0.1 s worth"
    assert limiter.allow("calm"), "another sender is not starved by the flood"
    total = sum(limiter.allow(f"s{i}") for i in range(10_000))
    assert total <= acks.TOTAL_BURST and len(limiter) == acks.MAX_BUCKETS


def test_an_estop_always_latches_past_the_latches_a_robot_names() -> None:
    """One more sender's e-stop than the named latches holds the overflow latch: no latch is
    evicted, and no release, not even one in the overflow latch's name, clears it."""
    safety = Safety()
    senders = [f"op{i}" for i in range(MAX_LATCHES + 3)]
    for i, who in enumerate(senders):
        assert safety.on_command(cmd(i + 1, sender=who, estop=True), 0.0) is Verdict.ESTOP
    assert safety.latches == [*senders[:MAX_LATCHES], OVERFLOW]
    assert OVERFLOW_WORDS in safety.holders()
    for who in [*senders, OVERFLOW]:
        assert safety.on_command(cmd(99, sender=who, release=True), 0.0) is Verdict.LATCHED
    assert safety.latches == [OVERFLOW] and safety.estop_by == OVERFLOW
    assert safety.on_command(cmd(100, sender="late", estop=True), 0.0) is Verdict.ESTOP
    assert safety.latches == [OVERFLOW, "late"], "room again: a named latch"


def test_the_estop_lane_loses_no_latch() -> None:
    """More e-stops in one step than the lane holds: a newer one of a sender waiting takes
    the older one's place, and of the senders past the lane's room one is kept as the overflow
    e-stop (every other sender waiting still latches in its own name)."""
    box = Inbox()
    seq = itertools.count(1)
    senders = [f"e{i}" for i in range(MAX_ESTOPS + 10)]
    for who in senders:
        box.put(at(cmd(next(seq), sender=who, estop=True), 1))
    again = next(seq)
    box.put(at(cmd(again, sender="e0", estop=True), 1))
    kept = box.drain().estops
    assert len(kept) == MAX_ESTOPS
    assert {r.cmd.sender for r in kept} == {*senders[:MAX_ESTOPS - 1], OVERFLOW}
    assert [r.cmd.seq for r in kept if r.cmd.sender == "e0"] == [again]
