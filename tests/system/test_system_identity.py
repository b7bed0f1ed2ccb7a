"""Identities the router vouches for: one certificate per operator, commands only under its own
name, leases and e-stop latches bound to it, a restamped replay as the replayer's.

Before: every operator presented the same certificate (CN=operator), so the router could not
tell them apart; ``sender=alice`` in a new session moved alice's leased robot, bob released
alice's e-stop, and ``replay --restamp`` kept the recorded sender and so its lease. Now the
deploy's own files run as in ``test_system_security`` (the ``secured`` fixture: TLS router with
``--robots deploy/robots.toml``, a real databank and youBot agent as TLS clients), with alice's
and bob's certificates from ``make-certs.sh`` (CN = their names) and the router's per-operator
rules generated from the same fleet file.
"""

from __future__ import annotations

import time
from functools import partial
from pathlib import Path

import pytest
import zenoh

from kinesphere.clients.recording.traffic import TrafficRecorder
from kinesphere.keyexpr import Keys
from kinesphere.protocol import Command, LeaseAction, SpatialCommand, encode
from kinesphere.zconfig import session, session_config, undeclare
from support.network import KEYS
from support.system import SECURED_ROBOT as ROBOT
from support.system import Secured, at_pose, query_pose, robot_cert
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

POSE = ("limb_11", "distal_11", "left-forward-high", 2)


def _as(s: Secured, operator: str) -> zenoh.Config:
    """deploy/operator.json5 with ``operator``'s own certificate."""
    config = session_config(config_file=s.configs["operator"])
    for option in robot_cert(s.certs, operator, "operators")[1::2]:
        key, _, value = option.partition(":")
        config.insert_json5(key, value)
    return config


def _cli(s: Secured, name: str, operator: str, *args: str, sender: str = ""
         ) -> tuple[int, str]:
    """A command-line client run with ``operator``'s certificate, as ``sender`` (by default
    the operator itself)."""
    child = s.sup.spawn(name, [*args, "--zenoh-config", str(s.configs["operator"]),
                               *robot_cert(s.certs, operator, "operators"),
                               "--sender", sender or operator], expect_exit=True)
    return s.sup.wait(name, WAIT_S), child.tail()


def _put(config: zenoh.Config, key: str, *, sender: str, seq: int = 1,
         parts: list[SpatialCommand] | None = None, lease: LeaseAction = LeaseAction.NONE) -> None:
    cmd = Command(seq=seq, sent_ns=time.time_ns(), deadman=True, ttl_ms=0,
                  session=f"s{time.monotonic_ns()}", sender=sender, parts=parts or [], lease=lease)
    with session(config=config) as s:
        pub = s.declare_publisher(key)
        pub.put(encode(cmd))
        undeclare(pub)


def test_an_operator_speaks_only_under_its_own_name(secured: Secured) -> None:
    s, obs = secured, secured.obs
    alice, bob = _as(s, "alice"), _as(s, "bob")
    mine = Keys.signed(KEYS.command(ROBOT), "alice")
    _put(alice, mine, sender="alice", lease=LeaseAction.ACQUIRE)
    until(lambda: (st := obs.states.last(ROBOT)) is not None and st.lease_holder == "alice",
          WAIT_S, "alice's lease")
    before = obs.states.last(ROBOT)
    assert before is not None
    move = [SpatialCommand(*POSE)]
    # bob under alice's name: on her key the router refuses it; on his, the robot does
    _put(bob, mine, sender="alice", parts=move, lease=LeaseAction.TAKE)
    _put(bob, Keys.signed(KEYS.command(ROBOT), "bob"), sender="alice", parts=move,
         lease=LeaseAction.TAKE)
    _put(bob, KEYS.command(ROBOT), sender="alice", parts=move)  # the plain key: nobody may
    for key in (mine, KEYS.command(ROBOT)):
        until(partial(s.denied, f"Put (ingress) on {key} by CN=bob"), WAIT_S,
              f"the router to deny bob's put on {key}")
    _put(alice, mine, sender="alice", lease=LeaseAction.ACQUIRE, seq=2)  # traffic after his
    assert obs.states.wait_fresh([ROBOT], time.time_ns() + 300_000_000, WAIT_S)
    after = obs.states.last(ROBOT)
    assert after is not None and after.lease_holder == "alice"
    assert at_pose(after, dict(zip(before.joint_names, before.q, strict=True)), tol=1e-3)
    # `send` with bob's certificate and alice's name: the router drops it, the client says so
    # (within 1 s: an admitted command is acked within milliseconds; that it was dropped is
    # proven by the robot, which, heard afterwards, has not moved)
    code, out = _cli(s, "send-bob-as-alice", "bob", "send", ROBOT, *map(str, POSE), "--wait",
                     "20", "--timeout", "1", sender="alice")
    assert code == 1 and f"{ROBOT}: NO ACKNOWLEDGEMENT" in out, out
    assert obs.states.wait_fresh([ROBOT], time.time_ns() + 300_000_000, WAIT_S)
    assert at_pose(obs.states.last(ROBOT), dict(zip(before.joint_names, before.q, strict=True)),
                   tol=1e-3)
    _put(alice, mine, sender="alice", lease=LeaseAction.RELEASE, seq=3)


def test_only_the_latching_operator_releases_its_estop(secured: Secured) -> None:
    s, obs = secured, secured.obs
    code, out = _cli(s, "estop-alice", "alice", "estop", "--timeout", "20")
    assert code == 0 and f"{ROBOT}: estopped" in out, out
    until(lambda: (st := obs.states.last(ROBOT)) is not None and st.estop_by == "alice",
          WAIT_S, "the e-stop latched by alice")
    code, out = _cli(s, "release-bob", "bob", "estop", "--release", "--target", ROBOT,
                     "--timeout", "20")
    assert code == 1 and f"{ROBOT}: REJECTED: estopped" in out, out
    assert obs.states.wait_fresh([ROBOT], time.time_ns() + 300_000_000, WAIT_S)
    assert obs.state(ROBOT).status == "estop"
    code, out = _cli(s, "release-alice", "alice", "estop", "--release", "--target", ROBOT,
                     "--timeout", "20")
    assert code == 0 and f"{ROBOT}: released" in out, out


def test_a_restamped_replay_sends_as_the_replaying_operator(secured: Secured,
                                                              tmp_path: Path) -> None:
    s, obs = secured, secured.obs
    recording = tmp_path / "alice.mcap"
    with session(config=session_config(config_file=s.configs["operator"])) as watcher:
        rec = TrafficRecorder(watcher, KEYS, recording)  # the shared certificate watches

        def recording_states() -> bool:  # its subscription has reached the router
            return rec.tally.by_type.get("RobotState", 0) > 0

        until(recording_states, WAIT_S, "the recorder to hear the robot")
        code, out = _cli(s, "send-alice", "alice", "send", ROBOT, *map(str, POSE), "--wait",
                         "20")
        assert code == 0, out
        until(lambda: rec.tally.by_type.get("Command", 0) >= 1, WAIT_S, "alice's command")
        rec.close()
    target = query_pose(obs.session, "youbot", *POSE).joints
    until(lambda: at_pose(obs.states.last(ROBOT), target), WAIT_S, "alice's pose")
    until(lambda: not obs.state(ROBOT).lease_holder,
          WAIT_S * 2, "alice's lease to expire")
    code, out = _cli(s, "replay-bob", "bob", "replay", str(recording), "--restamp",
                     "--wait", "20")
    assert code == 0 and "replayed" in out, out
    until(lambda: obs.state(ROBOT).lease_holder == "bob",
          WAIT_S, "bob's replayed commands leasing the robot to bob")
