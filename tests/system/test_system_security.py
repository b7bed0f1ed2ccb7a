"""The deploy/ configs as shipped: mutual TLS, role-based access control, per-robot identity.

Certificates come from deploy/make-certs.sh (roles, and robots youbot-1 and baxter-1 of
deploy/robots.toml); the JSON5 files are deploy/'s with only the certificate directory and
the port rewritten. A real databank (writes enabled on a copy) and a real youBot agent (with
its own certificate, CN=youbot-1, as kinesphere-agent@.service passes it) run behind
``kinesphere router --robots deploy/robots.toml`` as TLS clients, so the rules are checked
against the services' real traffic, not a stand-in.
"""

from __future__ import annotations

import re
import time
from functools import partial
from pathlib import Path

import pytest
import zenoh

from kinesphere.clients.link import operator_id
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.procs import Child
from kinesphere.protocol import (
    Ack,
    AckStage,
    Command,
    Pose,
    RecordRequest,
    RobotState,
    SpatialCommand,
    decode,
    encode,
)
from kinesphere.zconfig import (
    close_session,
    open_session,
    session,
    session_config,
    undeclare,
)
from support.network import KEYS
from support.paths import DEPLOY
from support.system import (
    SECURED_OTHER,
    SECURED_ROBOT,
    Secured,
    at_pose,
    listeners,
    make_certs,
    query_pose,
    robot_cert,
)
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

ROBOT = SECURED_ROBOT
OTHER = SECURED_OTHER
POSE_A = ("limb_11", "distal_11", "left-high", 2)
POSE_B = ("limb_11", "distal_11", "right-high", 2)


def test_every_deploy_config_loads() -> None:
    files = sorted(DEPLOY.glob("*.json5"))
    assert {f.stem for f in files} >= {"router", "databank", "agent", "operator", "superuser"}
    for f in files:
        config = zenoh.Config.from_file(str(f))
        assert config.get_json("transport/link/tls/root_ca_certificate")
    router = zenoh.Config.from_file(str(DEPLOY / "router.json5"))
    assert router.get_json("access_control/enabled") == "true"
    assert router.get_json("transport/link/tls/enable_mtls") == "true"


def test_only_the_router_listens(secured: Secured) -> None:
    """Before: client-mode services were fine, but a peer told only to connect listened on
    every interface in plain TCP, past the router's TLS and access control."""
    s = secured
    found = {name: listeners(child.pid) for name, child in s.sup.children.items()
             if child.alive()}
    assert found["router"] == [f"127.0.0.1:{s.port}"], found
    assert found["databank"] == [] and found["agent"] == [], found


DENIED_TIMEOUT_S = 1.0
"""``send --timeout`` where the router drops the command: an admitted command is acked within
milliseconds, and what proves the drop is the router's log and the robot's own state, not
how long the client waited (its 5 s default would only be idle time)."""


def _spawn_send(s: Secured, role: str, pose: tuple[str, str, str, int],
                operator: str = "", timeout: float | None = None) -> Child:
    """``kinesphere send`` with a role's deploy config (and an operator's own certificate
    and name), as an operator would run it (``--timeout`` if given), started."""
    name = f"send-{role}-{operator}-{pose[2]}"
    own = [*robot_cert(s.certs, operator, "operators"), "--sender", operator] if operator \
        else []
    answers = ["--timeout", f"{timeout:g}"] if timeout is not None else []
    return s.sup.spawn(name, ["send", ROBOT, *map(str, pose), "--zenoh-config",
                              str(s.configs[role]), *own, "--wait", "20", *answers],
                       expect_exit=True)


def _ended(s: Secured, child: Child) -> tuple[int, str]:
    """A started ``send``'s exit status and output."""
    return s.sup.wait(child.name, WAIT_S), child.tail()


def test_only_the_operator_moves_robots(secured: Secured) -> None:
    """An admitted operator, by its own certificate and name; the shared CN=operator
    certificate only watches."""
    s, obs = secured, secured.obs
    a = query_pose(obs.session, "youbot", *POSE_A).joints
    b = query_pose(obs.session, "youbot", *POSE_B).joints
    code, out = _ended(s, _spawn_send(s, "operator", POSE_A, operator="alice"))
    assert code == 0 and f"{ROBOT}: reached" in out, out
    until(lambda: at_pose(obs.states.last(ROBOT), a), WAIT_S, "the operator's pose")
    before = obs.states.last(ROBOT)
    assert before is not None

    # the router drops these: each client must say so (both run at once: they wait alike)
    for child in [_spawn_send(s, role, POSE_B, timeout=DENIED_TIMEOUT_S)
                  for role in ("superuser", "operator")]:
        code, out = _ended(s, child)
        assert code == 1 and f"{ROBOT}: NO ACKNOWLEDGEMENT" in out, out
    for role, config in (("robot", s.robot_config(ROBOT)),
                         ("databank", session_config(config_file=s.configs["databank"]))):
        cmd = Command(seq=0, sent_ns=time.time_ns(), parts=[SpatialCommand(*POSE_B)],
                      deadman=True, ttl_ms=0, sender=f"intruding-{role}")
        with session(config=config) as intruder:
            intruder.put(KEYS.command(ROBOT), encode(cmd))
            intruder.put(KEYS.command("*"), encode(cmd))
    signed = Keys.signed(KEYS.command(ROBOT), operator_id())  # what `send` puts on
    for cn, key in (("superuser", signed), ("operator", signed), (ROBOT, KEYS.command("*")),
                    (ROBOT, KEYS.command(ROBOT)), ("databank", KEYS.command(ROBOT))):
        until(partial(s.denied, f"Put (ingress) on {key} by CN={cn}"), WAIT_S,
              f"the router to log the denied command of CN={cn}")

    # the robot never saw those commands: same command seq, same pose, long after
    assert obs.states.wait_fresh([ROBOT], time.time_ns() + 300_000_000, WAIT_S)
    after = obs.states.last(ROBOT)
    assert after is not None and after.last_command_seq == before.last_command_seq
    assert at_pose(after, a) and not at_pose(after, b, tol=1e-3)


def _record(role_config: Path, pose: Pose) -> list[zenoh.Reply]:
    req = RecordRequest(limb=pose.limb, origin=pose.origin, direction=pose.direction,
                        size=int(pose.size), joints=pose.joints)
    with session(session_config(config_file=role_config)) as s:
        return list(s.get(KEYS.record("youbot"), payload=encode(req), timeout=3.0))


def test_only_the_superuser_writes_the_ecl(secured: Secured) -> None:
    s = secured
    pose = query_pose(s.obs.session, "youbot", *POSE_A)
    assert all(r.ok is None for r in _record(s.configs["operator"], pose))
    until(lambda: s.denied("Query (ingress) on kinesphere/ecl/youbot/record by CN=operator"),
          WAIT_S, "the router to log the operator's denied write")
    replies = _record(s.configs["superuser"], pose)
    ok = [r.ok for r in replies if r.ok is not None]
    assert ok, [r.err.payload.to_bytes() for r in replies if r.err is not None]
    stored = decode(ok[0].payload.to_bytes(), Pose)
    assert stored.p_id == 2 and stored.joints == pytest.approx(pose.joints)


def _refused(config: zenoh.Config) -> bool:
    try:
        s = open_session(config=config)
    except KinesphereError:
        return True
    close_session(s)
    return False


def test_tls_refuses_sessions_without_a_ca_certificate(secured: Secured, tmp_path: Path) -> None:
    s = secured
    tls = "transport/link/tls"
    # no client certificate at all
    bare = session_config(config_file=s.configs["operator"])
    bare.insert_json5(f"{tls}/enable_mtls", "false")
    bare.insert_json5(f"{tls}/connect_certificate", "null")
    bare.insert_json5(f"{tls}/connect_private_key", "null")
    assert _refused(bare)
    # a certificate with the right role name, signed by another CA
    other = make_certs(tmp_path / "intruder", roles="operator")
    forged = session_config(config_file=s.configs["operator"])
    forged.insert_json5(f"{tls}/connect_certificate", f'"{other / "operator.pem"}"')
    forged.insert_json5(f"{tls}/connect_private_key", f'"{other / "operator.key"}"')
    assert _refused(forged)
    # plain tcp to the TLS port
    plain = session_config("client", connect=[f"tcp/127.0.0.1:{s.port}"], scouting=False)
    plain.insert_json5("connect/timeout_ms", "0")
    assert _refused(plain)
    # each refusal is logged as a denial naming the peer (before: a Zenoh warning, no peer)
    def logged(reason: str) -> bool:
        return s.denied(f"TLS handshake refused ({reason}") and re.search(
            rf"TLS handshake refused \({reason}[^)]*\) from 127\.0\.0\.1:\d+",
            s.router_log.read_text()) is not None

    for reason in ("peer sent no certificates", "invalid peer certificate",
                   "received corrupt message"):
        until(partial(logged, reason), WAIT_S,
              f"the router to log the refusal '{reason}' with the peer")
    # while the genuine operator certificate still connects
    assert not _refused(session_config(config_file=s.configs["operator"]))


def test_a_robot_cannot_speak_for_another(secured: Secured) -> None:
    """Before: any agent certificate put a spoofed e-stop on another robot's state key (it
    reached the operator 5/5) and declared ``alive/robot/ghost-robot``. Now youbot-1's
    certificate is admitted to youbot-1's keys only."""
    s, obs = secured, secured.obs
    acks: list[str] = []
    ack_sub = obs.session.declare_subscriber(KEYS.ack("*"), lambda smp: acks.append(
        str(smp.key_expr)))
    heard: list[bytes] = []
    spoof = RobotState(robot_id=OTHER, platform="baxter", seq=10**9, stamp_ns=time.time_ns(),
                       joint_names=[], q=[], qd=[], base_pose=[0.0, 0.0, 0.0], status="estop",
                       last_command_seq=-1, detail="SPOOFED")
    ack = Ack(robot_id=OTHER, sender="op", seq=1, stage=AckStage.ESTOPPED,
              stamp_ns=time.time_ns())
    with session(config=s.robot_config(ROBOT)) as robot_a:
        robot_a.put(KEYS.state(OTHER), encode(spoof))
        robot_a.put(KEYS.ack(OTHER), encode(ack))
        ghost = robot_a.liveliness().declare_token(KEYS.alive_robot("ghost-robot"))
        eavesdrop = robot_a.declare_subscriber(KEYS.command(OTHER),
                                               lambda smp: heard.append(smp.payload.to_bytes()))
        for what, key in (("Put", KEYS.state(OTHER)), ("Put", KEYS.ack(OTHER)),
                          ("Liveliness Token", KEYS.alive_robot("ghost-robot")),
                          ("Declare Subscriber", KEYS.command(OTHER))):
            until(partial(s.denied, f"{what} (ingress) on {key} by CN={ROBOT}"),
                  WAIT_S, f"the router to deny {what} on {key}")
        # the operator commands the other robot; then a fresh state of youbot-1 shows that
        # traffic crossed the router after the spoofs and the command
        stop = Command(seq=1, sent_ns=time.time_ns(), deadman=False, ttl_ms=0, stop=True,
                       sender="security-test")
        with session(session_config(config_file=s.configs["operator"])) as op:
            op.put(KEYS.command(OTHER), encode(stop))
        assert obs.states.wait_fresh([ROBOT], time.time_ns() + 300_000_000, WAIT_S)
        undeclare(ghost, eavesdrop)
    undeclare(ack_sub)
    assert obs.states.last(OTHER) is None, "a spoofed state reached the operator"
    assert "ghost-robot" not in obs.alive.robots
    assert KEYS.ack(OTHER) not in acks
    assert heard == [], "a robot heard another robot's commands"
    assert obs.state(ROBOT).detail != "SPOOFED"
