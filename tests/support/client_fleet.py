"""For the client tests against real robots: the databank and two agents (a PackBot and a
youBot) run as processes on a loopback hub of their own (``running_fleet``, the ``fleet``
fixture of ``tests/clients/conftest.py``); states are tracked with arrival times; a gamepad
operator runs in this process on its own session.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pygame
import zenoh

from kinesphere import zconfig
from kinesphere.clients import targets as tg
from kinesphere.clients.gamepad import mapfile
from kinesphere.clients.gamepad.inputs import pad
from kinesphere.clients.gamepad.teleop import Teleop
from kinesphere.clients.link import RobotLink
from kinesphere.clients.options import TeleopOptions
from kinesphere.protocol import RobotState, decode
from support.network import KEYS, awaiting_token
from support.paths import ROOT
from support.system import databank_args
from support.wait import WAIT_S, stop_process

TTL_MS = 300
PB, YB = "pb-1", "yb-1"
PLATFORMS = {PB: "packbot", YB: "youbot"}


class FleetProcess:
    """A kinesphere process joined to the hub; ready once its liveliness token appears."""

    def __init__(self, hub: zenoh.Session, endpoint: str, args: list[str], token: str,
                 log: Path) -> None:
        with awaiting_token(hub, token) as up:
            self.log = log.open("wb")
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "kinesphere.cli", *args,
                 "--connect", endpoint, "--listen", zconfig.LOOPBACK_ANY_PORT],
                cwd=ROOT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
                stdout=self.log, stderr=subprocess.STDOUT,
            )
            if not up.wait(WAIT_S):
                self.stop()
                raise RuntimeError(f"{args[:2]} did not come up; see {log}")

    def stop(self) -> None:
        stop_process(self.proc, timeout=15)
        self.log.close()


@dataclass(frozen=True)
class Heard:
    at: float
    state: RobotState


class StateHistory:
    """Every RobotState of every robot, with arrival times and waits on predicates."""

    def __init__(self, session: zenoh.Session) -> None:
        self.heard: dict[str, list[Heard]] = {}
        self._cond = threading.Condition()
        self._sub = session.declare_subscriber(KEYS.state("*"), self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        st = decode(sample.payload, RobotState)
        with self._cond:
            self.heard.setdefault(st.robot_id, []).append(Heard(time.monotonic(), st))
            self._cond.notify_all()

    def wait(self, robot: str, pred: Callable[[Heard], bool], what: str,
             after: float = 0.0) -> Heard:
        """The first state of ``robot`` heard after ``after`` that satisfies ``pred``."""
        deadline = time.monotonic() + WAIT_S
        with self._cond:
            while True:
                for h in self.heard.get(robot, []):
                    if h.at > after and pred(h):
                        return h
                left = deadline - time.monotonic()
                if left <= 0 or not self._cond.wait(left):
                    last = self.heard.get(robot, [None])[-1]
                    raise AssertionError(f"{robot}: timed out waiting for {what}; last {last}")

    def since(self, robot: str, t: float) -> list[Heard]:
        with self._cond:
            return [h for h in self.heard.get(robot, []) if h.at >= t]

    def close(self) -> None:
        zconfig.undeclare(self._sub)


def speeds(hs: list[Heard]) -> list[tuple[float, float]]:
    """(robot time s, base speed m/s) between consecutive states."""
    out = []
    for a, b in zip(hs, hs[1:], strict=False):
        dt = (b.state.stamp_ns - a.state.stamp_ns) / 1e9
        if dt > 0:
            dx = b.state.base_pose[0] - a.state.base_pose[0]
            dy = b.state.base_pose[1] - a.state.base_pose[1]
            out.append((b.state.stamp_ns / 1e9, (dx * dx + dy * dy) ** 0.5 / dt))
    return out


def at_rest(robot: str, track: StateHistory, after: float) -> Heard:
    """The first state after ``after`` where the base has neither moved nor turned since the
    previous one and no joint moves."""
    prev: list[Heard] = []

    def still(h: Heard) -> bool:
        v = speeds([prev[-1], h]) if prev else []
        turned = abs(h.state.base_pose[2] - prev[-1].state.base_pose[2]) if prev else 1.0
        prev.append(h)
        return (bool(v) and v[0][1] < 1e-3 and turned < 1e-4
                and max(map(abs, h.state.qd)) < 1e-3)

    return track.wait(robot, still, "the robot at rest", after)


@dataclass
class ClientFleet:
    hub: zenoh.Session
    endpoint: str
    track: StateHistory


def running_fleet(logs: Path) -> Iterator[ClientFleet]:
    """The databank and the two agents as processes on a hub of their own, until closed."""
    args = databank_args(list(PLATFORMS.values()))
    with zconfig.loopback_hub() as (hub, endpoint):
        track = StateHistory(hub)
        children: list[FleetProcess] = []
        try:
            children.append(FleetProcess(hub, endpoint, ["databank", "serve", *args],
                                         KEYS.alive_databank_all(), logs / "databank.log"))
            for rid, platform in PLATFORMS.items():
                groups = ["--group", "sweepers"] if rid == PB else []
                children.append(FleetProcess(hub, endpoint,
                                             ["agent", platform, "--id", rid, *groups],
                                             KEYS.alive_robot(rid), logs / f"{rid}.log"))
            for rid in PLATFORMS:
                track.wait(rid, lambda h: True, "a first state")
            yield ClientFleet(hub, endpoint, track)
        finally:
            for c in reversed(children):
                c.stop()
            track.close()


@contextmanager
def operator(fleet: ClientFleet, target: tg.Target, sender: str | None = None, take: bool = False
             ) -> Iterator[tuple[Teleop, pad.PygameInput]]:
    """A gamepad client on its own session (as ``sender``), with its catalogues loaded."""
    pygame.event.clear()
    inp = pad.PygameInput(mapfile.load())
    with zconfig.session(config=zconfig.loopback_config(fleet.endpoint)) as s:
        link = RobotLink(s, KEYS, sender=sender)
        try:
            assert link.wait_subscribers(target.keys(KEYS), WAIT_S) == []
            assert link.wait_for(lambda lk: set(lk.states()) >= set(PLATFORMS), WAIT_S)
            op = Teleop(link, mapfile.load(), target, TeleopOptions(rate_hz=30.0, ttl_ms=TTL_MS),
                        take=take)
            assert op.tick(inp.poll()).members, "the target reaches a robot we hear"
            assert op.catalogues.arrived.wait(WAIT_S)
            yield op, inp
        finally:
            link.close()
