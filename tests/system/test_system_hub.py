"""No single point of failure in ``kinesphere up``'s topology, and ``status`` that never misses.

Before: the hub every process joined was a service's own session (the databank's in the quick
start); killed, nothing (no command, no e-stop) reached the still-running robots, and a new
``estop`` process had nobody to join. ``status`` in peer mode listed no robot in 5 of 10 runs.
Now ``kinesphere up`` starts a router child that serves nothing else and everything else joins
it as a client. This test runs that exact start-up (:class:`kinesphere.deploy.up.Demo`), kills
the databank and an agent with SIGKILL, and checks that every other process keeps talking; the
README's five-minute tour (the same shape by hand) is run as written and checked the same way.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import sys
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TextIO

import pytest
import zenoh
from rich.console import Console

from kinesphere.cli import main
from kinesphere.deploy.plan import PlannedRobot, UpOptions
from kinesphere.deploy.up import Demo
from kinesphere.keyexpr import KEYS
from kinesphere.procs import Child, Supervisor
from kinesphere.protocol import Ack, Command, SpatialCommand, decode, encode
from kinesphere.zconfig import free_port, loopback_config, undeclare
from support.paths import ROOT
from support.system import Observer, at_pose, log_of
from support.transcripts import Step, section, unprinted
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

ROBOTS = {"youbot-1": "youbot", "khepera-1": "khepera", "khepera-2": "khepera"}
ARM = ("limb_11", "distal_11", "left-high", 2)  # youBot's arm


@pytest.fixture
def demo(tmp_path: Path) -> Iterator[Demo]:
    opts = UpOptions(robots=[PlannedRobot(p, r) for r, p in ROBOTS.items()], phrases=[],
                     out=tmp_path / "out", headless=True, start_timeout=WAIT_S * 2,
                     extra_agent_args=["--control-rate", "250"])
    d = Demo(opts, console=Console(file=open(tmp_path / "up.log", "w"), width=120))
    try:
        d.start()
        yield d
    finally:
        assert d.shutdown() == [], "processes left behind"


ESTOP_SENDER = "hub-operator"
"""Who the ``kinesphere estop`` processes of these tests are to the robots."""


class EstopAcks:
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
        undeclare(self._sub)


def statuses(demo: Demo) -> dict[str, str]:
    return {r: s.status for r, s in demo.recorder.snapshot().items()}


class _ThreadsOwnStdout(io.TextIOBase):
    """``sys.stdout`` for commands run at once in threads: each thread's own buffer (a thread
    that is not running one writes where ``sys.stdout`` wrote before)."""

    def __init__(self) -> None:
        self._local = threading.local()
        self._before = sys.stdout

    def _out(self) -> TextIO:
        out: TextIO = getattr(self._local, "buf", None) or self._before
        return out

    def writable(self) -> bool:
        return True

    def write(self, text: str) -> int:
        return self._out().write(text)

    def run(self, func: Callable[[], object]) -> str:
        """``func()`` in this thread; what it printed."""
        buf = self._local.buf = io.StringIO()
        try:
            func()
        finally:
            del self._local.buf
        return buf.getvalue()


def status_lists(endpoint: str, mode: str, runs: int = 1) -> list[set[str]]:
    """Robots each of ``runs`` ``kinesphere status`` (in-process, all at once, each on a
    session of its own) lists as alive with a state."""
    own = _ThreadsOwnStdout()
    argv = ["status", "--json", "--connect", endpoint, "--mode", mode, "--timeout", "10"]
    with ThreadPoolExecutor(runs) as pool, contextlib.redirect_stdout(own):
        printed = list(pool.map(lambda _i: own.run(lambda: main(argv)), range(runs)))
    infos = [json.loads(out) for out in printed]
    return [{r for r, v in info["robots"].items() if v["alive"] and v["state"]}
            for info in infos]


def test_kill_any_service_and_the_rest_keep_talking(demo: Demo) -> None:
    sup, ep, tokens = demo.sup, demo.endpoint, demo.alive
    assert tokens is not None
    runs = status_lists(ep, "client", runs=10)
    assert all(r == set(ROBOTS) for r in runs), runs

    # the databank dies: robots keep running, the hub keeps routing
    held = demo.recorder.snapshot()["youbot-1"]
    sup.kill("databank")
    until(lambda: not tokens.databanks, WAIT_S, "the databank's token to go")
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
    until(lambda: "khepera-2" not in tokens.robots, WAIT_S, "khepera-2's token to go")
    alive = {r for r in ROBOTS if r != "khepera-2"}

    # a new operator process joins the hub and e-stops every robot still alive; each acks it
    acks = EstopAcks(demo._session)
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
    assert status_lists(ep, "client") == [alive]


SETUP = (["make", "install"], [".", ".venv/bin/activate"])
"""The tour's commands that are not ``kinesphere``: the set-up this suite already ran."""
TOUR = "A five-minute tour"


def tour() -> tuple[list[Step], str]:
    """The steps of the README's "A five-minute tour", and the sender it names."""
    steps = [step for block in section("README.md", TOUR) for step in block.steps]
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start = text.index(f"\n## {TOUR}\n")
    sender = re.search(r"\(here `([^`]+)`\)", text[start : text.find("\n## ", start + 1)])
    assert sender, "the README's tour no longer names its sender"
    return steps, sender.group(1)


def log(child: Child, since: int = 0) -> str:
    """What ``child`` printed (after the first ``since`` bytes of its log)."""
    with log_of(child).open("rb") as f:
        f.seek(since)
        return f.read().decode("utf-8", errors="replace")


def wait_printed(sup: Supervisor, child: Child, shown: list[str], since: int = 0) -> None:
    """Wait until ``child`` printed every line ``shown`` (failing at once if a child died)."""

    def done() -> bool:
        sup.check()
        return not unprinted(shown, log(child, since))

    until(done, WAIT_S, f"{child.name} to print what the README shows",
          explain=lambda: (unprinted(shown, log(child, since)), child.tail()))


def test_the_readme_tour_runs_as_written(sup: Supervisor) -> None:
    """The README's five-minute tour, command by command as processes, each printing what the
    README shows (the router and the view on free ports instead of 7447 and 8080, which other
    suites on this machine may hold); then, in that topology, ``status`` lists every live robot
    every time, as a peer and as a client (ten runs of each at once, each on a session of its
    own; before the router: 5 of 10 as a peer), and with the databank killed a new ``estop``
    process still reaches every robot."""
    steps, sender = tour()
    sup.env["KINESPHERE_SENDER"] = sender
    port, view_port = free_port(), free_port()
    ep = f"tcp/127.0.0.1:{port}"
    jobs: list[str] = []
    for n, step in enumerate(steps):
        if step.words[0] != "kinesphere":
            if step.words[0] == "kill":
                break
            assert step.words in SETUP, f"the tour runs {step.words}: teach this test to"
            continue
        command = step.words[1]
        args = step.words[1:] + (["--listen", ep] if command == "router" else ["--connect", ep])
        if command == "view":
            args += ["--port", str(view_port)]
        if step.background:
            jobs.append(command)
            wait_printed(sup, sup.spawn(command, args), step.shown)
        else:
            child = sup.spawn(f"{n}-{command}", args, expect_exit=True)
            assert sup.wait(child.name, WAIT_S) == 0, log(child)
            assert not unprinted(step.shown, log(child)), log(child)
        if command == "view":
            with urllib.request.urlopen(f"http://127.0.0.1:{view_port}/", timeout=WAIT_S) as page:
                assert page.status == 200 and b"<html" in page.read(4096).lower()
    kill = steps[n]
    assert kill.words == ["kill", *(f"%{i}" for i in range(1, len(jobs) + 1))], (kill, jobs)
    assert jobs == ["router", "databank", "agent", "view"] and n == len(steps) - 1

    robots = {"yb-1", "k2"}
    sup.spawn("agent-k2", ["agent", "khepera", "--id", "k2", "--connect", ep])
    obs = Observer(loopback_config(ep))
    try:
        obs.wait_alive(robots, databank=True, sup=sup)
        for mode in ("peer", "client"):
            runs = status_lists(ep, mode, runs=10)
            assert all(r == robots for r in runs), f"{mode}: {runs}"
        sup.kill("databank")
        until(lambda: not obs.alive.databanks, WAIT_S, "the databank's token to go")
        acks = EstopAcks(obs.session)
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
        # the databank again, as the tour started it, for the tour's last step
        bank = next(step for step in steps if step.words[1:2] == ["databank"])
        before = log_of(sup.children["databank"]).stat().st_size  # the log is appended to
        wait_printed(sup, sup.spawn("databank", bank.words[1:] + ["--connect", ep]), bank.shown,
                     since=before)
        assert sup.stop("agent-k2") == 0
    finally:
        obs.close()
    codes = sup.stop_all()  # the tour's kill: SIGTERM to each, and each stops cleanly
    assert {job: codes[job] for job in jobs} == dict.fromkeys(jobs, 0), {
        job: sup.children[job].tail() for job in jobs if codes[job] != 0}
