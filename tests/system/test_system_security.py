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
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from kinesphere.deploy.procs import Supervisor
from kinesphere.errors import KinesphereError
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
    free_port,
    open_session,
    session,
    session_config,
    undeclare,
)
from support.network import KEYS
from support.paths import DEPLOY
from support.system import (
    SHIPPED_DBS,
    Observer,
    at_pose,
    databank_args,
    listeners,
    localize,
    make_certs,
    port_open,
    query_pose,
    supervisor,
)
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

ROBOT = "youbot-1"
OTHER = "baxter-1"
"""Another robot of deploy/robots.toml (not running): youbot-1's certificate may not speak
for it."""
POSE_A = ("limb_11", "distal_11", "left-high", 2)
POSE_B = ("limb_11", "distal_11", "right-high", 2)


@dataclass
class Secured:
    sup: Supervisor
    configs: dict[str, Path]
    certs: Path
    port: int
    router_log: Path
    obs: Observer

    def denied(self, text: str) -> bool:
        return any("access denied" in line and text in line
                   for line in self.router_log.read_text(errors="replace").splitlines())

    def robot_config(self, robot_id: str) -> zenoh.Config:
        """deploy/agent.json5 with ``robot_id``'s own certificate, as the agent unit runs it."""
        config = session_config(config_file=self.configs["agent"])
        for option in robot_cert(self.certs, robot_id)[1::2]:
            key, _, value = option.partition(":")
            config.insert_json5(key, value)
        return config


def robot_cert(certs: Path, robot_id: str) -> list[str]:
    """The --cfg options that give an agent its robot's own certificate (CN = robot id)."""
    tls = "transport/link/tls"
    return ["--cfg", f'{tls}/connect_certificate:"{certs}/robots/{robot_id}.pem"',
            "--cfg", f'{tls}/connect_private_key:"{certs}/robots/{robot_id}.key"']


def _db_copy(tmp: Path) -> str:
    """A private copy of the youBot databank, so an ECL write never touches shipped data."""
    args = databank_args(["youbot"])
    src = SHIPPED_DBS / "youbot.sqlite" if args[0] == "--platform" else Path(args[1].split("=")[1])
    dst = tmp / "youbot.sqlite"
    shutil.copy(src, dst)
    return f"youbot={dst}"


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Secured]:
    tmp = tmp_path_factory.mktemp("secured")
    db = _db_copy(tmp)
    certs = make_certs(tmp / "certs", robots=f"{ROBOT} {OTHER}")
    port = free_port()
    configs = localize(tmp / "conf", certs, port)
    for sup in supervisor(tmp / "logs"):
        router = sup.spawn("router", ["router", "--config", str(configs["router"]),
                                      "--robots", str(DEPLOY / "robots.toml")])
        until(lambda s=sup: s.check() or port_open(port), WAIT_S, "the TLS router to listen")
        sup.spawn("databank", ["databank", "serve", "--db", db, "--allow-writes", "--replica",
                               "db-1", "--zenoh-config", str(configs["databank"])])
        sup.spawn("agent", ["agent", "youbot", "--id", ROBOT, "--rate", "250",
                            "--zenoh-config", str(configs["agent"]), *robot_cert(certs, ROBOT)])
        obs = Observer(session_config(config_file=configs["operator"]))
        try:
            obs.wait_alive({ROBOT}, databank=True, sup=sup)
            yield Secured(sup, configs, certs, port, router.log_path, obs)
        finally:
            obs.close()


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


def _send(s: Secured, role: str, pose: tuple[str, str, str, int]) -> tuple[int, str]:
    """``kinesphere send`` with a role's deploy config, as an operator would run it: its exit
    status and output."""
    name = f"send-{role}-{pose[2]}"
    child = s.sup.spawn(name, ["send", ROBOT, *map(str, pose), "--zenoh-config",
                               str(s.configs[role]), "--wait", "20"], expect_exit=True)
    return s.sup.wait(name, WAIT_S), child.tail()


def test_only_the_operator_moves_robots(secured: Secured) -> None:
    s, obs = secured, secured.obs
    a = query_pose(obs.session, "youbot", *POSE_A).joints
    b = query_pose(obs.session, "youbot", *POSE_B).joints
    code, out = _send(s, "operator", POSE_A)
    assert code == 0 and f"{ROBOT}: reached" in out, out
    until(lambda: at_pose(obs.states.last(ROBOT), a), WAIT_S, "the operator's pose")
    before = obs.states.last(ROBOT)
    assert before is not None

    code, out = _send(s, "superuser", POSE_B)  # the router drops it: the client must say so
    assert code == 1 and f"{ROBOT}: NO ACKNOWLEDGEMENT" in out, out
    for role, config in (("robot", s.robot_config(ROBOT)),
                         ("databank", session_config(config_file=s.configs["databank"]))):
        cmd = Command(seq=0, sent_ns=time.time_ns(), parts=[SpatialCommand(*POSE_B)],
                      deadman=True, ttl_ms=0, sender=f"intruding-{role}")
        with session(config=config) as intruder:
            intruder.put(KEYS.command(ROBOT), encode(cmd))
            intruder.put(KEYS.command("*"), encode(cmd))
    for cn, key in (("superuser", KEYS.command(ROBOT)), (ROBOT, KEYS.command("*")),
                    (ROBOT, KEYS.command(ROBOT)), ("databank", KEYS.command(ROBOT))):
        until(lambda cn=cn, key=key: s.denied(f"Put (ingress) on {key} by CN={cn}"), WAIT_S,
              f"the router to log the denied command of CN={cn}")

    # the robot never saw those commands: same command seq, same pose, long after
    assert obs.states.wait_fresh([ROBOT], time.time_ns() + 300_000_000, WAIT_S)
    after = obs.states.last(ROBOT)
    assert after is not None and after.last_command_seq == before.last_command_seq
    assert at_pose(after, a) and not at_pose(after, b, tol=1e-3)


def _record(role_config: Path, pose: Pose) -> list[zenoh.Reply]:
    req = RecordRequest(limb=pose.limb, origin=pose.origin, direction=pose.direction,
                        size=int(pose.size), joints=pose.joints)
    with session(config_file=role_config) as s:
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
    for reason in ("peer sent no certificates", "invalid peer certificate",
                   "received corrupt message"):
        until(lambda reason=reason: s.denied(f"TLS handshake refused ({reason}") and
              re.search(rf"TLS handshake refused \({reason}[^)]*\) from 127\.0\.0\.1:\d+",
                        s.router_log.read_text()) is not None,
              WAIT_S, f"the router to log the refusal '{reason}' with the peer")
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
            until(lambda what=what, key=key: s.denied(f"{what} (ingress) on {key} by "
                                                      f"CN={ROBOT}"),
                  WAIT_S, f"the router to deny {what} on {key}")
        # the operator commands the other robot; then a fresh state of youbot-1 shows that
        # traffic crossed the router after the spoofs and the command
        stop = Command(seq=1, sent_ns=time.time_ns(), deadman=False, ttl_ms=0, stop=True,
                       sender="security-test")
        with session(config_file=s.configs["operator"]) as op:
            op.put(KEYS.command(OTHER), encode(stop))
        assert obs.states.wait_fresh([ROBOT], time.time_ns() + 300_000_000, WAIT_S)
        undeclare(ghost, eavesdrop)
    ack_sub.undeclare()  # type: ignore[no-untyped-call]
    assert obs.states.last(OTHER) is None, "a spoofed state reached the operator"
    assert "ghost-robot" not in obs.alive.robots
    assert KEYS.ack(OTHER) not in acks
    assert heard == [], "a robot heard another robot's commands"
    assert obs.states.last(ROBOT) is not None and obs.states.last(ROBOT).detail != "SPOOFED"
