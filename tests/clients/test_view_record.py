"""``kinesphere record`` / ``replay``: a session to MCAP and back, on real Zenoh sessions.

A publisher puts commands (robot, all and group keys), states, acks, a recorded pose and one
undecodable payload, spaced in time; a recorder writes them to MCAP. The file validates with
the ``mcap`` library's own reader (summary, schemas, channels, counts). A replay puts the
commands and states back, a second recorder records the replay, and both recordings hold
the same messages in the same order with the original spacing.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
import zenoh
from mcap.reader import make_reader

from kinesphere import protocol as pr
from kinesphere import zconfig
from kinesphere.clients.mcaplog import McapWriter, read
from kinesphere.clients.recording.traffic import TrafficRecorder, replay, tapped_keys
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.robots.agent.ordering import Ordering, Received
from support.network import NO_ROBOTS, OWN_KEYS
from support.wait import until

GAP_S = 0.05


def session_messages() -> list[tuple[str, pr.Message]]:
    part = pr.SpatialCommand("limb_11", "distal_11", "left-high", 3)
    out: list[tuple[str, pr.Message]] = []
    for i in range(4):
        out.append((OWN_KEYS.command("r1"), pr.Command(seq=i, sent_ns=time.time_ns(), parts=[part],
                                                   deadman=True, ttl_ms=300, sender="t")))
        out.append((OWN_KEYS.state("r1"), pr.RobotState(
            robot_id="r1", platform="baxter", seq=i, stamp_ns=time.time_ns(),
            joint_names=["a", "b"], q=[0.1 * i, -0.25], qd=[0.0, 1.5e-7],
            base_pose=[0.0, 0.0, 0.1], status="moving", last_command_seq=i)))
    out.append((OWN_KEYS.ack("r1"), pr.Ack(robot_id="r1", sender="t", seq=3,
                                           stage=pr.AckStage.REACHED,
                                       stamp_ns=time.time_ns())))
    out.append((OWN_KEYS.command("*"), pr.Command(seq=9, sent_ns=time.time_ns(), deadman=False,
                                              ttl_ms=0, estop=True, stop=True, sender="t")))
    out.append((OWN_KEYS.group_command("arms"), pr.Command(seq=10, sent_ns=time.time_ns(),
                                                      deadman=False, ttl_ms=0, sender="t")))
    out.append((OWN_KEYS.changed("baxter"), pr.Pose(platform="baxter", limb="limb_11",
                                                 origin="distal_11", direction="left-high",
                                                 size=3.0, joints={"right_s0": 0.5}, k_id=4)))
    return out


def test_record_replay_round_trip(tmp_path: Path) -> None:
    first, second = tmp_path / "first.mcap", tmp_path / "second.mcap"
    sent = session_messages()
    with zconfig.loopback_hub() as (hub, endpoint):
        with zconfig.session(config=zconfig.loopback_config(endpoint)) as pub_s, \
                zconfig.session(config=zconfig.loopback_config(endpoint)) as rec_s:
            rec = TrafficRecorder(rec_s, OWN_KEYS, first)
            pubs = {key: pub_s.declare_publisher(key) for key, _ in sent}
            for pub in pubs.values():
                assert zconfig.wait_matching(pub, 20.0), "the recorder never subscribed"
            pub_s.put(OWN_KEYS.state("r1"), b"\xc1 not messagepack")  # counted, not recorded
            t_first = time.monotonic()
            for key, msg in sent:
                pubs[key].put(pr.encode(msg))
                time.sleep(GAP_S)  # the spacing a replay must keep, not synchronisation
            span = time.monotonic() - t_first
            until(lambda: rec.tally.recorded == len(sent), 20.0, "every message recorded",
                  explain=lambda: rec.tally)
            tally = rec.close()
            assert tally.undecodable == 1
            zconfig.undeclare(*pubs.values())

            # the file is valid MCAP with one schema per type and one channel per key
            with first.open("rb") as f:
                summary = make_reader(f).get_summary()
            assert summary is not None and summary.statistics is not None
            assert summary.statistics.message_count == len(sent)
            assert {s.name for s in summary.schemas.values()} == {
                "kinesphere.Command", "kinesphere.RobotState", "kinesphere.Ack",
                "kinesphere.Pose"}
            assert all(s.encoding == "jsonschema" for s in summary.schemas.values())
            assert {c.topic for c in summary.channels.values()} == {k for k, _ in sent}
            got = list(read(first))
            assert [(r.key, r.message) for r in got] == sent  # contents equal, in order

            # replay commands and states; a second recorder sees exactly those again (the
            # replay waits until its publishers match the recorder, which has just subscribed)
            rec2 = TrafficRecorder(rec_s, OWN_KEYS, second)
            put_at: list[float] = []
            done = replay(pub_s, first, "all", wait=20.0, keys=OWN_KEYS, answers_for=NO_ROBOTS,
                          on_put=lambda k, m: put_at.append(time.monotonic()))
            wanted = [(k, m) for k, m in sent if isinstance(m, (pr.Command, pr.RobotState))]
            assert done.sent == len(wanted) and done.unheard == []
            until(lambda: rec2.tally.recorded == done.sent, 20.0, "every replayed message recorded",
                  explain=lambda: rec2.tally)
            rec2.close()
    again = list(read(second))
    assert [(r.key, r.message) for r in again] == wanted
    replay_span = put_at[-1] - put_at[0]
    assert replay_span >= 0.8 * (span - 4 * GAP_S)  # the original spacing, not a burst
    assert len(tapped_keys(OWN_KEYS)) == 5


def test_a_burst_over_every_tapped_key_is_recorded_in_the_order_it_was_put(
        tmp_path: Path) -> None:
    """No spacing at all: the recording keeps the order of arrival across keys (a command,
    then the state and ack it caused), not the order in which per-key threads got to run."""
    path = tmp_path / "burst.mcap"
    kinds = session_messages()[8:] + session_messages()[:2]  # ack, *, group, changed, cmd, state
    burst = [kinds[i % len(kinds)] for i in range(300)]
    with zconfig.loopback_hub() as (hub, endpoint):
        with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
            rec = TrafficRecorder(s, OWN_KEYS, path)
            pubs = {k: hub.declare_publisher(k, congestion_control=zenoh.CongestionControl.BLOCK)
                    for k, _ in kinds}
            assert zconfig.unmatched(pubs, 20.0) == []
            for key, msg in burst:
                pubs[key].put(pr.encode(msg))
            until(lambda: rec.tally.recorded == len(burst), 20.0, "the burst recorded",
                  explain=lambda: rec.tally)
            rec.close()
            zconfig.undeclare(*pubs.values())
    assert [(r.key, r.message) for r in read(path)] == burst


def test_a_replay_says_which_keys_nobody_heard(tmp_path: Path) -> None:
    path = tmp_path / "two.mcap"
    cmds = [(OWN_KEYS.command(rid), pr.Command(seq=1, sent_ns=time.time_ns(), deadman=False,
                                           ttl_ms=0, stop=True, sender="t"))
            for rid in ("r1", "r2")]
    with McapWriter(path) as w:
        for i, (key, cmd) in enumerate(cmds):
            w.write(key, cmd, time.time_ns() + i)
    with zconfig.loopback_hub() as (hub, endpoint):
        with pytest.raises(KinesphereError) as err:
            replay(hub, path, wait=0.2, keys=OWN_KEYS)  # nobody at all: nothing is put
        assert err.value.code == "unavailable"
        message = err.value.message
        assert OWN_KEYS.command("r1") in message and "nothing replayed" in message
        with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
            got: list[str] = []
            sub = s.declare_subscriber(OWN_KEYS.command("r1"),
                                       lambda sample: got.append(str(sample.key_expr)))
            probe = hub.declare_publisher(OWN_KEYS.command("r1"))
            assert zconfig.wait_matching(probe, 20.0)  # the hub knows r1's subscriber now
            zconfig.undeclare(probe)
            # r1 heard at once, r2 never
            done = replay(hub, path, wait=0.2, keys=OWN_KEYS, answers_for=NO_ROBOTS)
            assert done.sent == 2 and done.unheard == [OWN_KEYS.command("r2")]
            until(lambda: got == [OWN_KEYS.command("r1")], 20.0, "r1's command",
                  explain=lambda: got)
            zconfig.undeclare(sub)


def test_bad_recordings(tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(b"not an mcap file at all")
    with pytest.raises(KinesphereError) as err:
        list(read(bad))
    assert err.value.code == "malformed" and "MCAP" in err.value.message
    with pytest.raises(KinesphereError, match="choose one of"):
        with zconfig.loopback_hub() as (hub, _):
            replay(hub, bad, "everything", keys=OWN_KEYS)


def test_a_restamped_replay_is_new_to_robots_that_heard_the_original(tmp_path: Path) -> None:
    """As recorded, a replay is stale to a robot that heard the session (the agent's own
    ordering rules decide); restamped, each recorded session comes back as a fresh one of the
    replaying operator's, signed with its name, with the same order, sent now."""
    part = pr.SpatialCommand("limb_11", "distal_11", "left-high", 3)
    t0 = time.time_ns() - 3_600 * 10**9  # recorded an hour ago
    original = [pr.Command(seq=i, sent_ns=t0 + i * 10**7, parts=[part], deadman=True, ttl_ms=0,
                           sender=sender, session=session)
                for sender, session in (("alice", "s-1"), ("bob", "")) for i in range(3)]
    path = tmp_path / "s.mcap"
    with McapWriter(path) as w:
        for i, cmd in enumerate(original):
            w.write(OWN_KEYS.command("r1"), cmd, t0 + i * 10**6)

    def heard(ordering: Ordering, cmds: list[pr.Command]) -> list[str]:
        out = []
        for cmd in cmds:
            now = time.time_ns()
            err = ordering.admit(Received(cmd, time.monotonic_ns(), now), time.monotonic_ns())
            out.append("ok" if err is None else err.code)
        return out

    robot = Ordering()
    assert heard(robot, original) == ["ok"] * 6
    with zconfig.loopback_hub() as (hub, endpoint):
        with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
            got: list[tuple[str, pr.Command]] = []
            sub = s.declare_subscriber(Keys.subscribed(OWN_KEYS.command("r1")),
                                       lambda sample: got.append((str(sample.key_expr), pr.decode(
                                           sample.payload.to_bytes(), pr.Command))))
            assert replay(hub, path, "commands", speed=100.0, wait=20.0, keys=OWN_KEYS,
                          answers_for=NO_ROBOTS).sent == 6
            until(lambda: len(got) == 6, 20.0, "six messages")
            assert replay(hub, path, "commands", speed=100.0, restamp=True, keys=OWN_KEYS,
                          sender="carol", answers_for=NO_ROBOTS).sent == 6
            until(lambda: len(got) == 12, 20.0, "twelve messages")
            zconfig.undeclare(sub)
    as_recorded, restamped = [c for _, c in got[:6]], [c for _, c in got[6:]]
    assert as_recorded == original and {k for k, _ in got[:6]} == {OWN_KEYS.command("r1")}
    assert heard(robot, as_recorded) == ["stale"] * 6
    assert heard(robot, restamped) == ["ok"] * 6
    sessions = {c.session for c in restamped}
    assert len(sessions) == 2 and not sessions & {"s-1", ""}
    assert {k for k, _ in got[6:]} == {Keys.signed(OWN_KEYS.command("r1"), "carol")}
    assert [(c.sender, c.seq, c.parts) for c in restamped] == \
        [("carol", c.seq, c.parts) for c in original]
    assert all(c.sent_ns > original[-1].sent_ns + 3_000 * 10**9 for c in restamped)
