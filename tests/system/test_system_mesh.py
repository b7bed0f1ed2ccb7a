"""Three sites, three ``kinesphere router`` processes linked in a line (issue 16, item 3).

    operator site (router A) --- headquarters (router B, databank) --- robot site (router C)

Every process is a Zenoh client of its own site's router, so the operator's commands and
e-stops, and the robots' states, acks and liveliness tokens, cross both inter-router links
(three routers); the agents' pose queries and the operator's catalogue and pose queries cross
one (two routers). The site routers start before headquarters: a router keeps retrying a link,
so sites may come up in any order. Then the middle router is SIGKILLed while an operator
streams a drive: the robot, cut off from its operator, holds within its command's TTL (its
watchdog, not the 10 s link lease), keeps stepping and reporting at its own site, and obeys
again once the middle router is back and the links re-form.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh

from kinesphere.keyexpr import KEYS, Keys
from kinesphere.procs import Supervisor
from kinesphere.protocol import Ack, Command, SpatialCommand, decode, encode
from kinesphere.zconfig import free_port, session, session_config, undeclare, wait_matching
from support.paths import DEPLOY
from support.system import (
    Observer,
    at_pose,
    client_config,
    databank_args,
    localize,
    log_of,
    make_certs,
    port_open,
    query_pose,
    supervisor,
)
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

ROBOTS = {"youbot-1": "youbot", "nao-1": "nao"}
POSE_A = ("limb_11", "distal_11", "left-high", 2)
POSE_B = ("limb_11", "distal_11", "right-high", 2)
TTL_MS = 300
LATCHED_SEQ = 1000
AGENT_HZ = "250"  # two real-time agents, three routers and a databank share two cores in CI


@contextmanager
def acks_at(obs: Observer) -> Iterator[list[Ack]]:
    """Every robot's acks as ``obs``'s site receives them, while the block runs."""
    got: list[Ack] = []
    sub = obs.session.declare_subscriber(KEYS.ack("*"),
                                         lambda s: got.append(decode(s.payload, Ack)))
    try:
        yield got
    finally:
        undeclare(sub)


def start_router(sup: Supervisor, ports: dict[str, int], name: str) -> None:
    """Start (or restart) the router of site ``name``; the sites link to headquarters."""
    argv = ["router", "--listen", f"tcp/127.0.0.1:{ports[name]}"]
    if name != "hq":
        argv += ["--link", f"tcp/127.0.0.1:{ports['hq']}"]
    sup.spawn(f"router-{name}", argv)
    until(lambda: port_open(ports[name]), WAIT_S, f"router {name} to listen", guard=sup.check)


SENDER = "mesh-test"


@dataclass
class Mesh:
    sup: Supervisor
    ports: dict[str, int]
    configs: dict[str, Path]
    ops: Observer
    """The operator site's view (a client of router A)."""
    site: Observer
    """The robot site's view (a client of router C)."""
    tmp: Path

    def send(self, name: str, *args: str) -> None:
        """``kinesphere send all ...`` from the operator site; it must exit 0. The commands
        of the test's own session are the same operator's (``SENDER``): robots lease control
        to a sender."""
        child = self.sup.spawn(name, ["send", "all", *args, "--zenoh-config",
                                      str(self.configs["ops"]), "--wait", "20",
                                      "--sender", SENDER], expect_exit=True)
        code = self.sup.wait(name, WAIT_S)
        assert code == 0, f"{name} exited {code}:\n{child.tail()}"

    def estop(self, name: str, *args: str) -> None:
        child = self.sup.spawn(name, ["estop", *args, "--zenoh-config",
                                      str(self.configs["ops"]), "--wait", "20",
                                      "--sender", SENDER], expect_exit=True)
        code = self.sup.wait(name, WAIT_S)
        assert code == 0, f"{name} exited {code}:\n{child.tail()}"



@pytest.fixture(scope="module")
def mesh(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Mesh]:
    tmp = tmp_path_factory.mktemp("mesh")
    dbs = databank_args(sorted(set(ROBOTS.values())))
    ports = {name: free_port() for name in ("ops", "hq", "robots")}
    configs = {name: client_config(tmp / f"{name}.json5", f"tcp/127.0.0.1:{port}")
               for name, port in ports.items()}
    for sup in supervisor(tmp / "logs"):
        ops = site = None
        try:
            for name in ("ops", "robots", "hq"):  # sites first: they retry the link to hq
                start_router(sup, ports, name)
            sup.spawn("databank", ["databank", "serve", *dbs, "--zenoh-config",
                                   str(configs["hq"]), "--replica", "hq-1"])
            for rid, platform in ROBOTS.items():
                sup.spawn(f"agent-{rid}", ["agent", platform, "--id", rid,
                                           "--control-rate", AGENT_HZ,
                                           "--zenoh-config", str(configs["robots"])])
            ops = Observer(mode="client", connect=[f"tcp/127.0.0.1:{ports['ops']}"])
            site = Observer(mode="client", connect=[f"tcp/127.0.0.1:{ports['robots']}"])
            # liveliness and states of the robot site reach the operator site: both links up
            ops.wait_alive(set(ROBOTS), databank=True, sup=sup)
            site.wait_alive(set(ROBOTS), databank=True, sup=sup)
            yield Mesh(sup, ports, configs, ops, site, tmp)
        finally:
            for obs in (ops, site):
                if obs is not None:
                    obs.close()


def test_commands_states_queries_and_estop_cross_the_mesh(mesh: Mesh) -> None:
    ops = mesh.ops
    # pose queries from the operator site, answered at headquarters (one link)
    a = {rid: query_pose(ops.session, p, *POSE_A).joints for rid, p in ROBOTS.items()}
    b = {rid: query_pose(ops.session, p, *POSE_B).joints for rid, p in ROBOTS.items()}
    assert a != b

    # a command crosses both links; each agent resolves it at headquarters (one link) and the
    # operator site sees every robot's state arrive at its pose (both links, the other way)
    mesh.send("send-a", *map(str, POSE_A))
    until(lambda: all(at_pose(ops.states.last(r), a[r]) for r in ROBOTS), WAIT_S,
          "every robot at pose A, seen from the operator site",
          explain=lambda: f"{ops.describe()}\nwanted {a}")

    # an e-stop from the operator site latches every robot at the robot site
    mesh.estop("estop")
    until(lambda: all(ops.state(r).status == "estop" for r in ROBOTS),
          WAIT_S, "every robot to latch the e-stop", explain=ops.describe)
    latched = Command(seq=LATCHED_SEQ, sent_ns=time.time_ns(), parts=[SpatialCommand(*POSE_B)],
                      deadman=True, ttl_ms=0, sender=SENDER)
    with acks_at(ops) as acks:  # each robot's answer crosses both links back
        ops.session.put(KEYS.command("*"), encode(latched))
        until(lambda: {a.robot_id for a in acks if a.sender == SENDER
                       and a.seq == LATCHED_SEQ and a.code == "estopped"} == set(ROBOTS),
              WAIT_S, "every robot to refuse the command while latched (acks)",
              explain=lambda: acks[-5:])
    until(lambda: all(ops.state(r).last_command_seq == LATCHED_SEQ for r in ROBOTS),
          WAIT_S, "every robot to report the refused command", explain=ops.describe)
    assert all(at_pose(ops.states.last(r), a[r]) and ops.state(r).status == "estop"
               for r in ROBOTS), f"a latched robot moved:\n{ops.describe()}"

    # released from the operator site, the robots obey the next command
    mesh.estop("release", "--release", "--target", "all")
    until(lambda: all(ops.state(r).status != "estop" for r in ROBOTS),
          WAIT_S, "every robot to release the e-stop", explain=ops.describe)
    mesh.send("send-b", *map(str, POSE_B))
    until(lambda: all(at_pose(ops.states.last(r), b[r]) for r in ROBOTS), WAIT_S,
          "every robot at pose B after the release",
          explain=lambda: f"{ops.describe()}\nwanted {b}")


def test_lost_middle_router_robot_holds_within_ttl(mesh: Mesh) -> None:
    sup, ops, site = mesh.sup, mesh.ops, mesh.site
    robot = "youbot-1"
    phrase = mesh.tmp / "drive.toml"
    phrase.write_text(f'name = "drive"\nttl_ms = {TTL_MS}\n[[step]]\nduration = 120\n'
                      'parts = []\ndrive = "forward 0.5"\n')
    sup.spawn("play", ["play", str(phrase), "--target", robot, "--zenoh-config",
                       str(mesh.configs["ops"]), "--wait", "20"])

    def x() -> float:
        return site.state(robot).base_pose[0]

    x0 = x()
    until(lambda: x() > x0 + 0.05, WAIT_S, "the youbot to drive", guard=sup.check)

    # the link between the sites goes: headquarters' router dies mid-stream
    sup.kill("router-hq")
    killed = time.monotonic()
    until(lambda: site.state(robot).status == "holding", 10.0,
          "the youbot to hold", explain=site.describe)
    to_hold = time.monotonic() - killed
    assert to_hold < TTL_MS / 1000 + 1.5, f"held {to_hold:.2f} s after the link went"

    # it brakes to rest and keeps stepping and reporting at its own site
    last = x()
    while True:
        assert site.states.wait_fresh([robot], time.time_ns() + 200_000_000, 5.0), \
            "the robot stopped reporting at its own site"
        last, before = x(), last
        if abs(last - before) < 0.002:
            break
        assert time.monotonic() - killed < TTL_MS / 1000 + 5.0, "the base did not stop"
    # the operator site sees the robots' tokens go with the link (not after the lease)
    assert ops.alive.wait_for(lambda al: not (set(ROBOTS) & al.robots), 5.0), \
        f"the operator site still sees {sorted(ops.alive.robots)}"
    sup.kill("play")
    print(f"middle router killed: holding after {to_hold:.2f} s, "
          f"base at rest after {time.monotonic() - killed:.2f} s")

    # headquarters comes back: the site routers re-link by themselves, the databank's and the
    # robots' sessions find it again, and a new command crosses the mesh
    start_router(sup, mesh.ports, "hq")
    until(lambda: set(ROBOTS) <= ops.alive.robots and bool(ops.alive.databanks), WAIT_S,
          "the mesh to re-form (robots and databank alive at the operator site)",
          guard=sup.check)
    a = query_pose(ops.session, "youbot", *POSE_A).joints
    mesh.send("send-after", *map(str, POSE_A))
    until(lambda: at_pose(ops.states.last(robot), a), WAIT_S, "the youbot at pose A again",
          explain=ops.describe)


def test_tls_mesh_each_router_judges_its_own_clients(tmp_path: Path, sup: Supervisor) -> None:
    """deploy/router.json5 on two linked routers: the routers admit each other by the
    ``router`` certificate, an operator's command crosses to the other site, and a command
    from a role without the right (superuser) is denied, and logged, by its own site's router."""
    certs = make_certs(tmp_path / "certs", operators="alice")
    hq, hall = free_port(), free_port()
    configs = localize(tmp_path / "conf", certs, hq)
    fleet = ["--robots", str(DEPLOY / "robots.toml")]  # admits operator alice by name
    router = {"hq": sup.spawn("router-hq", ["router", "--config", str(configs["router"]),
                                            *fleet]),
              "hall": sup.spawn("router-hall", [
                  "router", "--config", str(configs["router"]), *fleet,
                  "--listen", f"tls/127.0.0.1:{hall}", "--link", f"tls/localhost:{hq}"])}
    until(lambda: port_open(hq) and port_open(hall), WAIT_S, "both TLS routers to listen",
          guard=sup.check)
    key = Keys.signed(KEYS.command("hall-robot"), "alice")
    got: list[str] = []
    arrived = threading.Condition()

    def on_command(sample: zenoh.Sample) -> None:
        with arrived:
            got.append(sample.payload.to_bytes().decode())
            arrived.notify_all()

    def at(port: int, role: str, name: str = "") -> AbstractContextManager[zenoh.Session]:
        config = session_config(config_file=configs[role], connect=[f"tls/localhost:{port}"])
        if name:  # an operator's own certificate, CN = its name
            tls = "transport/link/tls"
            config.insert_json5(f"{tls}/connect_certificate", f'"{certs}/operators/{name}.pem"')
            config.insert_json5(f"{tls}/connect_private_key", f'"{certs}/operators/{name}.key"')
        return session(config=config)

    with (at(hall, "operator") as robot_side, at(hq, "operator", "alice") as operator,
          at(hq, "superuser") as superuser):
        sub = robot_side.declare_subscriber(key, on_command)
        pub = operator.declare_publisher(key)
        assert wait_matching(pub, WAIT_S), "the command subscriber never reached hq"
        superuser.put(key, b"superuser")
        until(lambda: "access denied: Put (ingress) on " + key + " by CN=superuser"
              in log_of(router["hq"]).read_text(errors="replace"), WAIT_S,
              "hq to deny and log the superuser's command")
        deadline = time.monotonic() + WAIT_S
        with arrived:  # put again until one arrives: a put on a link just made may be dropped
            while "operator" not in got and time.monotonic() < deadline:
                pub.put(b"operator")
                arrived.wait_for(lambda: "operator" in got, 1.0)
        undeclare(pub, sub)
    assert got and set(got) == {"operator"}, f"a denied command crossed the mesh: {got}"
    assert "access denied" not in log_of(router["hall"]).read_text(errors="replace")
