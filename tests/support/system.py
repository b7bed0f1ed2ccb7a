"""Helpers for the system tests: real processes, real routers, waits on events with deadlines.

Not a test module itself (pytest collects nothing here); the system tests import it.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import psutil
import pytest
import zenoh

from kinesphere.deploy.watch import Alive, StateRecorder, watch_alive
from kinesphere.procs import Child, Supervisor
from kinesphere.protocol import Pose, RobotState, decode, error_from_reply
from kinesphere.services.ecl.store import DATA_DIR
from kinesphere.zconfig import (
    close_session,
    free_port,
    open_session,
    session_config,
    undeclare,
)
from support.network import KEYS
from support.paths import DEPLOY
from support.wait import WAIT_S, until

SHIPPED_DBS = DATA_DIR
"""The databanks shipped with the platforms."""


def ctrl_c_reaches_it() -> None:
    """A ``preexec_fn``: undo an inherited SIG_IGN for SIGINT, so that the command starts with
    Python's Ctrl-C handler as it would in a terminal. A job started with ``&`` by a
    non-interactive shell ignores SIGINT, and so does every process it starts: a ``make test``
    run that way sent its Ctrl-Cs to commands that never heard them."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def databank_args(platforms: list[str]) -> list[str]:
    """The shipped databanks, or prebuilt ones from $KINESPHERE_TEST_DBS (DIR/<platform>.sqlite)."""
    if all((SHIPPED_DBS / f"{p}.sqlite").exists() for p in platforms):
        return [a for p in platforms for a in ("--platform", p)]
    dev = os.environ.get("KINESPHERE_TEST_DBS")
    if dev and all((Path(dev) / f"{p}.sqlite").exists() for p in platforms):
        return [a for p in platforms for a in ("--db", f"{p}={Path(dev) / p}.sqlite")]
    pytest.fail(f"no {'/'.join(platforms)} databanks in {SHIPPED_DBS} (or $KINESPHERE_TEST_DBS): "
                "run `kinesphere ecl build --all` or restore them with git")


def port_open(port: int, host: str = "127.0.0.1") -> bool:
    with socket.socket() as s:
        s.settimeout(0.2)
        return s.connect_ex((host, port)) == 0


def listeners(pid: int) -> list[str]:
    """``ip:port`` of every TCP/UDP socket process ``pid`` listens on (or has bound, for UDP)."""
    out = []
    for c in psutil.Process(pid).net_connections(kind="inet"):
        if c.status == psutil.CONN_LISTEN or (c.type == 2 and not c.raddr):  # 2: SOCK_DGRAM
            out.append(f"{c.laddr.ip}:{c.laddr.port}")
    return sorted(out)


def loopback(addresses: list[str]) -> bool:
    return all(a.startswith(("127.", "::1:", "::ffff:127.")) for a in addresses)


def make_certs(out: Path, *extra: str, roles: str | None = None, robots: str = "",
               operators: str = "") -> Path:
    env = dict(os.environ, ROBOTS=robots, OPERATORS=operators)
    if roles is not None:
        env["ROLES"] = roles
    subprocess.run([str(DEPLOY / "make-certs.sh"), str(out), *extra], check=True, env=env,
                   capture_output=True, timeout=60)
    return out


def localize(out: Path, certs: Path, port: int) -> dict[str, Path]:
    """Copies of deploy/*.json5 with this machine's cert paths and a loopback port."""
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    for src in sorted(DEPLOY.glob("*.json5")):
        text = (src.read_text()
                .replace("/etc/kinesphere/certs", str(certs))
                .replace("tls/0.0.0.0:7447", f"tls/127.0.0.1:{port}")
                .replace("tls/router:7447", f"tls/localhost:{port}"))
        dst = out / src.name
        dst.write_text(text)
        files[src.stem] = dst
    return files


def client_config(path: Path, endpoint: str) -> Path:
    """A plain (tcp) client-mode config: every byte goes through the router."""
    path.write_text(
        f'{{ mode: "client", connect: {{ endpoints: ["{endpoint}"] }}, '
        "scouting: { multicast: { enabled: false } } }\n"
    )
    return path


def query_pose(s: zenoh.Session, platform: str, limb: str, origin: str, direction: str,
               size: float) -> Pose:
    for reply in s.get(KEYS.pose(platform, limb, origin, direction, size), timeout=10.0):
        if reply.ok is not None:
            return decode(reply.ok.payload.to_bytes(), Pose)
        if reply.err is not None:
            raise error_from_reply(reply.err.payload.to_bytes())
    raise AssertionError(f"no databank answered for {platform}")


def at_pose(state: RobotState | None, joints: dict[str, float], tol: float = 0.02) -> bool:
    if state is None:
        return False
    q = dict(zip(state.joint_names, state.q, strict=True))
    return all(abs(q[name] - value) <= tol for name, value in joints.items())


class Observer:
    """A session that watches liveliness and every robot's state."""

    def __init__(self, config: zenoh.Config | None = None, mode: str | None = None,
                 connect: Sequence[str] | None = None) -> None:
        self.session = open_session(config or session_config(mode, connect=connect))
        self.states = StateRecorder(KEYS, history=False).start(self.session)
        self.alive: Alive
        self.alive, self._subs = watch_alive(self.session, KEYS)

    def wait_alive(self, robots: set[str], databank: bool, sup: Supervisor,
                   timeout: float = WAIT_S) -> None:
        def up() -> bool:
            sup.check()
            return robots <= self.alive.robots and (bool(self.alive.databanks) or not databank)

        until(up, timeout, f"liveliness of {sorted(robots)} and databank={databank}")
        until(lambda: robots <= set(self.states.snapshot()), timeout, "first robot states")

    def state(self, robot_id: str) -> RobotState:
        """The robot's last state; fails the test if none was heard yet."""
        state = self.states.last(robot_id)
        if state is None:
            pytest.fail(f"no state of {robot_id} heard yet")
        return state

    def describe(self) -> str:
        """The robots' last states, for failure messages."""
        return "\n".join(
            f"{rid}: {st.status} ({st.detail}) cmd {st.last_command_seq} "
            f"q={dict(zip(st.joint_names, (round(v, 3) for v in st.q), strict=True))}"
            for rid, st in sorted(self.states.snapshot().items()))

    def close(self) -> None:
        undeclare(*self._subs)
        self.states.close()
        close_session(self.session)


def router_hub(sup: Supervisor) -> str:
    """A ``kinesphere router`` listening on a free loopback port (the hub every process
    connects to); its endpoint, once it listens."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    sup.spawn("router", ["router", "--listen", endpoint])
    until(lambda: port_open(port), WAIT_S, "the router to listen", guard=sup.check)
    return endpoint


def log_of(child: Child) -> Path:
    """The log file of ``child``: the tests' supervisors keep one per child."""
    assert child.log_path is not None, f"{child.name} writes to the test's own output"
    return child.log_path


def log_folder(sup: Supervisor) -> Path:
    """The folder of ``sup``'s logs (the tests' supervisors always keep one)."""
    assert sup.log_dir is not None, "this supervisor keeps no logs"
    return sup.log_dir


def supervisor(log_dir: Path) -> Iterator[Supervisor]:
    """A Supervisor that stops everything and checks for leftovers at teardown."""
    sup = Supervisor(log_dir)
    try:
        yield sup
    finally:
        sup.stop_all()
        left = sup.leftovers()
        assert not left, f"processes left behind: {left}"


# --- the deploy's own files, secured --------------------------------------------------------

SECURED_ROBOT = "youbot-1"
"""The robot of deploy/robots.toml that runs behind the secured router (its own
certificate)."""
SECURED_OTHER = "baxter-1"
"""Another robot of deploy/robots.toml (not running): youbot-1's certificate may not speak
for it."""


@dataclass
class Secured:
    """The deploy/ configs as shipped, running: a TLS router with ``--robots
    deploy/robots.toml``, a databank (writes on a copy) and a youBot agent as TLS clients, the
    certificates of make-certs.sh (roles, both robots, operators alice and bob)."""

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


def robot_cert(certs: Path, robot_id: str, folder: str = "robots") -> list[str]:
    """The --cfg options that give an agent its robot's own certificate (CN = robot id), or
    (``folder="operators"``) an operator's own."""
    tls = "transport/link/tls"
    return ["--cfg", f'{tls}/connect_certificate:"{certs}/{folder}/{robot_id}.pem"',
            "--cfg", f'{tls}/connect_private_key:"{certs}/{folder}/{robot_id}.key"']


def _db_copy(tmp: Path) -> str:
    """A private copy of the youBot databank, so an ECL write never touches shipped data."""
    args = databank_args(["youbot"])
    src = SHIPPED_DBS / "youbot.sqlite" if args[0] == "--platform" else Path(args[1].split("=")[1])
    dst = tmp / "youbot.sqlite"
    shutil.copy(src, dst)
    return f"youbot={dst}"


def secured_system(tmp: Path) -> Iterator[Secured]:
    """:class:`Secured` running in ``tmp`` until the generator is closed."""
    db = _db_copy(tmp)
    certs = make_certs(tmp / "certs", robots=f"{SECURED_ROBOT} {SECURED_OTHER}",
                       operators="alice bob")
    port = free_port()
    configs = localize(tmp / "conf", certs, port)
    for sup in supervisor(tmp / "logs"):
        router = sup.spawn("router", ["router", "--config", str(configs["router"]),
                                      "--robots", str(DEPLOY / "robots.toml")])
        until(lambda: port_open(port), WAIT_S, "the TLS router to listen", guard=sup.check)
        sup.spawn("databank", ["databank", "serve", "--db", db, "--allow-writes", "--replica",
                               "db-1", "--zenoh-config", str(configs["databank"])])
        sup.spawn("agent", ["agent", "youbot", "--id", SECURED_ROBOT, "--control-rate", "250",
                            "--zenoh-config", str(configs["agent"]),
                            *robot_cert(certs, SECURED_ROBOT)])
        obs = Observer(session_config(config_file=configs["operator"]))
        try:
            obs.wait_alive({SECURED_ROBOT}, databank=True, sup=sup)
            yield Secured(sup, configs, certs, port, log_of(router), obs)
        finally:
            obs.close()
