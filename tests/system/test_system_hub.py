"""No single point of failure in ``kinesphere up``'s topology, and ``status`` that never misses.

Before: the hub every process joined was a service's own session (the databank's in the quick
start); killed, nothing (no command, no e-stop) reached the still-running robots, and a new
``estop`` process had nobody to join. ``status`` in peer mode listed no robot in 5 of 10 runs.
Now ``kinesphere up`` starts a router child that serves nothing else and everything else joins
it as a client. This test runs that exact start-up (:class:`kinesphere.deploy.up.Demo`), kills
the databank and an agent with SIGKILL, and checks that every other process keeps talking.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from rich.console import Console

from kinesphere.cli import main
from kinesphere.deploy.plan import PlannedRobot, UpOptions
from kinesphere.deploy.procs import Supervisor
from kinesphere.deploy.up import Demo
from kinesphere.keyexpr import KEYS
from kinesphere.protocol import Ack, Command, SpatialCommand, decode, encode
from kinesphere.zconfig import free_port, loopback_config
from support.system import Observer, at_pose, databank_args, port_open
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

ROBOTS = {"youbot-1": "youbot", "khepera-1": "khepera", "khepera-2": "khepera"}
ARM = ("limb_11", "distal_11", "left-high", 2)  # youBot's arm


@pytest.fixture
def demo(tmp_path: Path) -> Iterator[Demo]:
    opts = UpOptions(robots=[PlannedRobot(p, r) for r, p in ROBOTS.items()], phrases=[],
                     out=tmp_path / "out", headless=True, start_timeout=WAIT_S * 2,
                     extra_agent_args=["--rate", "250"])
    d = Demo(opts, console=Console(file=open(tmp_path / "up.log", "w"), width=120))
    try:
        d.start()
        yield d
    finally:
        assert d.shutdown() == [], "processes left behind"


ESTOP_SENDER = "hub-operator"
"""Who the ``kinesphere estop`` processes of these tests are to the robots."""


class Acks:
    """Every Ack heard, as (robot, sender, stage)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.seen: list[tuple[str, str, str]] = []
        self._sub = session.declare_subscriber(KEYS.ack("*"), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        ack = decode(sample.payload.to_bytes(), Ack)
        self.seen.append((ack.robot_id, ack.sender, str(ack.stage)))

    def estopped(self) -> set[str]:
        """Robots that acked an e-stop of the ``kinesphere estop`` process (``--sender``)."""
        return {r for r, sender, stage in self.seen
                if stage == "estopped" and sender == ESTOP_SENDER}

    def close(self) -> None:
        self._sub.undeclare()  # type: ignore[no-untyped-call]


def statuses(demo: Demo) -> dict[str, str]:
    return {r: s.status for r, s in demo.recorder.snapshot().items()}


def status_lists(endpoint: str, mode: str, capsys: pytest.CaptureFixture[str]) -> set[str]:
    """Robots ``kinesphere status`` lists as alive with a state (run in-process)."""
    main(["status", "--json", "--connect", endpoint, "--mode", mode, "--timeout", "10"])
    info = json.loads(capsys.readouterr().out)
    return {r for r, v in info["robots"].items() if v["alive"] and v["state"]}


def test_kill_any_service_and_the_rest_keep_talking(
    demo: Demo, capsys: pytest.CaptureFixture[str]
) -> None:
    sup, ep = demo.sup, demo.endpoint
    assert demo.alive is not None
    runs = [status_lists(ep, "client", capsys) for _ in range(10)]
    assert all(r == set(ROBOTS) for r in runs), runs

    # the databank dies: robots keep running, the hub keeps routing
    held = demo.recorder.snapshot()["youbot-1"]
    sup.kill("databank")
    until(lambda: not demo.alive.databanks, WAIT_S, "the databank's token to go")  # type: ignore[union-attr]
    assert demo.recorder.wait_fresh(ROBOTS, time.time_ns(), WAIT_S), "robots went quiet"

    # a command now cannot be resolved: each robot keeps its pose and says why
    cmd = Command(seq=1, sent_ns=time.time_ns(), parts=[SpatialCommand(*ARM)], deadman=True,
                  ttl_ms=0, sender="hub-test")
    demo._session.put(KEYS.command("youbot-1"), encode(cmd))
    until(lambda: statuses(demo).get("youbot-1") == "databank_unreachable", WAIT_S,
          "the youBot to report databank_unreachable", explain=lambda: statuses(demo))
    assert at_pose(demo.recorder.snapshot()["youbot-1"],
                   dict(zip(held.joint_names, held.q, strict=True)))

    # an agent dies too: the others are not affected
    sup.kill("agent-khepera-2")
    until(lambda: "khepera-2" not in demo.alive.robots, WAIT_S, "khepera-2's token to go")  # type: ignore[union-attr]
    alive = {r for r in ROBOTS if r != "khepera-2"}

    # a new operator process joins the hub and e-stops every robot still alive; each acks it
    acks = Acks(demo._session)
    try:
        estop = sup.spawn("estop", ["estop", "--connect", ep, "--mode", "client",
                                    "--sender", ESTOP_SENDER], expect_exit=True)
        assert sup.wait("estop", WAIT_S) == 0, estop.tail()
        until(lambda: all(statuses(demo).get(r) == "estop" for r in alive), WAIT_S,
              "every live robot to latch the e-stop", explain=lambda: statuses(demo))
        until(lambda: acks.estopped() >= alive, WAIT_S, "every live robot to ack the e-stop",
              explain=lambda: acks.seen)
    finally:
        acks.close()
    assert status_lists(ep, "client", capsys) == alive



def test_quick_start_topology_peers_around_a_router(
    sup: Supervisor, capsys: pytest.CaptureFixture[str]
) -> None:
    """The README's quick start: ``kinesphere router``, then the databank, agents and operator
    commands with their default (peer) options, here pointed at the router's free port."""
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    robots = {"k1", "k2"}
    sup.spawn("router", ["router", "--listen", ep])
    until(lambda: sup.check() or port_open(port), WAIT_S, "the router")
    sup.spawn("databank", ["databank", "serve", *databank_args(["khepera"]), "--connect", ep])
    for r in sorted(robots):
        sup.spawn(f"agent-{r}", ["agent", "khepera", "--id", r, "--connect", ep])
    obs = Observer(loopback_config(ep))
    try:
        obs.wait_alive(robots, databank=True, sup=sup)
        # status lists every live robot, 10 runs of 10, as a peer and as a client
        # (before: 5 of 10 in peer mode)
        for mode in ("peer", "client"):
            runs = [status_lists(ep, mode, capsys) for _ in range(10)]
            assert all(r == robots for r in runs), f"{mode}: {runs}"
        sup.kill("databank")
        until(lambda: not obs.alive.databanks, WAIT_S, "the databank's token to go")
        acks = Acks(obs.session)
        try:
            estop = sup.spawn("estop", ["estop", "--connect", ep, "--sender", ESTOP_SENDER],
                              expect_exit=True)
            assert sup.wait("estop", WAIT_S) == 0, estop.tail()
            until(lambda: all(getattr(obs.states.last(r), "status", "") == "estop"
                              for r in robots), WAIT_S, "both robots to latch the e-stop",
                  explain=obs.describe)
            until(lambda: acks.estopped() >= robots, WAIT_S, "both robots to ack the e-stop",
                  explain=lambda: acks.seen)
        finally:
            acks.close()
    finally:
        obs.close()
