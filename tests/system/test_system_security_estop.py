"""A fleet e-stop reaches a secured fleet: deploy/'s mutual TLS and access control as
shipped, on two linked routers (the robots' site and an operator's host).

Certificates come from deploy/make-certs.sh (roles, robots youbot-1 and baxter-1, operators
alice and bob); both routers run ``kinesphere router --robots deploy/robots.toml``. The
robots are real agent processes with their own certificates (CN = robot id) behind the
site's router; alice runs ``kinesphere estop`` with her own certificate on the other host's
router. Before (268fb5e) every robot's query of the fleet e-stops in force was denied, so a
robot started during a fleet e-stop came up free; only an indirect test noticed.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from kinesphere.procs import Child, Supervisor
from kinesphere.protocol import RobotState
from kinesphere.zconfig import free_port, session_config
from support.agents import StateWatch
from support.paths import DEPLOY
from support.system import (
    Observer,
    localize,
    log_of,
    make_certs,
    port_open,
    robot_cert,
    supervisor,
)
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

FIRST, LATE = "youbot-1", "baxter-1"
"""Robots of deploy/robots.toml: one runs from the start, one starts during the e-stop."""


@dataclass
class Site:
    """Two linked TLS routers: ``site`` (the robots') and ``host`` (an operator's)."""

    sup: Supervisor
    certs: Path
    configs: dict[str, Path]
    ports: dict[str, int]
    obs: Observer

    def at(self, where: str) -> list[str]:
        """Options joining the router ``where`` with deploy's config of the role that
        follows (``--zenoh-config`` comes after them)."""
        return ["--cfg", f'connect/endpoints:["tls/localhost:{self.ports[where]}"]']

    def agent(self, platform: str, robot_id: str, name: str = "") -> Child:
        """The robot's agent as kinesphere-agent@.service runs it: its own certificate."""
        return self.sup.spawn(name or robot_id, [
            "agent", platform, "--id", robot_id, "--control-rate", "250", "--zenoh-config",
            str(self.configs["agent"]), *robot_cert(self.certs, robot_id), *self.at("site")],
            expect_exit=bool(name))

    def estop(self, name: str, operator: str, *args: str) -> tuple[int, str]:
        """``kinesphere estop`` run by ``operator`` on the other host, with its own
        certificate and name: its exit status and output."""
        child = self.sup.spawn(name, [
            "estop", *args, "--sender", operator, "--zenoh-config", str(self.configs["operator"]),
            *robot_cert(self.certs, operator, "operators"), *self.at("host")], expect_exit=True)
        return self.sup.wait(name, WAIT_S), child.tail()


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Site]:
    tmp_path = tmp_path_factory.mktemp("site")
    certs = make_certs(tmp_path / "certs", robots=f"{FIRST} {LATE}", operators="alice bob")
    ports = {"site": free_port(), "host": free_port()}
    configs = localize(tmp_path / "conf", certs, ports["site"])
    fleet = ["--config", str(configs["router"]), "--robots", str(DEPLOY / "robots.toml")]
    for sup in supervisor(tmp_path / "logs"):
        sup.spawn("router-site", ["router", *fleet])
        sup.spawn("router-host", ["router", *fleet, "--listen",
                                  f"tls/127.0.0.1:{ports['host']}", "--link",
                                  f"tls/localhost:{ports['site']}"])
        until(lambda: all(map(port_open, ports.values())), WAIT_S,
              "both TLS routers to listen", guard=sup.check)
        obs = Observer(session_config(config_file=configs["operator"]))  # watches, at the site
        s = Site(sup, certs, configs, ports, obs)
        try:
            s.agent("youbot", FIRST)
            obs.wait_alive({FIRST}, databank=False, sup=sup)
            yield s
        finally:
            obs.close()


def _latched(st: RobotState | None, by: str) -> bool:
    return st is not None and st.status == "estop" and st.estop_by == by


def test_a_fleet_estop_from_another_host_reaches_a_secured_fleet(site: Site) -> None:
    """alice's e-stop crosses both routers' access control and latches the running robot in
    her name; a robot started while it is in force comes up latched (its very first state)
    from what the running one holds; bob cannot release it; alice's release frees both."""
    s = site
    code, out = s.estop("estop-alice", "alice", "--target", "all")
    assert code == 0 and f"{FIRST}: estopped" in out, out
    until(lambda: _latched(s.obs.states.last(FIRST), "alice"), WAIT_S,
          f"{FIRST} latched in alice's name", explain=s.obs.describe)

    late = StateWatch(s.obs.session, LATE)
    try:
        s.agent("baxter", LATE)
        s.obs.wait_alive({FIRST, LATE}, databank=False, sup=s.sup)
        until(lambda: bool(late.states), WAIT_S, f"a state of {LATE}")
        st: RobotState = late.states[0]
        assert _latched(st, "alice"), \
            f"{LATE}'s first state is not latched: {st.status} ({st.detail})"
        assert "fleet e-stop in force" in st.detail
        assert all(x.last_command_seq < 0 for x in late.states), "it obeyed a command"

        code, out = s.estop("release-bob", "bob", "--release", "--target", "all")
        assert code == 1 and out.count("REJECTED: estopped: e-stop still latched by alice") \
            == 2, out  # bob holds no e-stop: nobody is released
        assert s.obs.state(FIRST).estop_by == "alice" and late.states[-1].status == "estop"

        code, out = s.estop("release-alice", "alice", "--release", "--target", "all")
        assert code == 0 and f"{FIRST}: released" in out and f"{LATE}: released" in out, out
        late.wait(lambda x: x.status != "estop", "the late robot released")
    finally:
        late.close()
    for router in ("router-site", "router-host"):  # nothing of this was denied on the way
        log = log_of(s.sup.children[router]).read_text(errors="replace")
        assert "access denied" not in log, log


def test_a_second_agent_with_a_running_robot_id_refuses(site: Site) -> None:
    """The id claim crosses the access control too: the robot's own certificate run twice
    (a copied unit file) is refused, naming the host and pid where the first runs (its
    answer on its presence key; before, only the liveliness token got through, so the
    refusal could not say where), and the first runs on."""
    s = site
    s.obs.wait_alive({FIRST}, databank=False, sup=s.sup)
    twin = s.agent("youbot", FIRST, name="twin")
    code = s.sup.wait("twin", WAIT_S)
    first = s.sup.children[FIRST].pid
    assert code == 2 and f"robot id '{FIRST}' is already running: youbot on host " \
        f"{socket.gethostname().split('.')[0]} (pid {first})" in twin.tail(), twin.tail()
    s.obs.states.wait_fresh([FIRST], time.time_ns() + 300_000_000, WAIT_S)
    assert s.sup.children[FIRST].alive()
