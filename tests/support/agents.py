"""For the agent tests: the real databank process, agents, state and ack watchers, an operator.

Everything is real: Zenoh sessions on ``tcp/127.0.0.1:<free port>`` with scouting off, the
databank service as a subprocess (``kinesphere databank serve``), MuJoCo and Ruckig in the
agents, which run in this process so tests can record their Ruckig outputs. Tests wait on
events (a state matching a predicate, a liveliness token), never on sleeps. The shared hub and
databank are fixtures (``tests/conftest.py``).
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypedDict, Unpack

import numpy as np
import zenoh

from kinesphere import zconfig
from kinesphere.closing import Closable
from kinesphere.deploy.watch import Alive
from kinesphere.laban import Direction
from kinesphere.protocol import (
    Ack,
    Catalogue,
    Command,
    Drive,
    LeaseAction,
    LimbEntry,
    Pose,
    RobotState,
    SpatialCommand,
    decode,
    encode,
    error_from_reply,
)
from kinesphere.robots.agent.body import Body
from kinesphere.robots.agent.controller import Controller
from kinesphere.robots.agent.fleet import FleetHost, RobotSpec
from kinesphere.robots.agent.options import Ros2BodyOptions
from kinesphere.robots.agent.runtime import Agent, AgentOptions
from support.network import KEYS, Hub, awaiting_token
from support.paths import ROOT
from support.wait import WAIT_S, stop_process
from support.watch import Watch

# --- the databank ---------------------------------------------------------------------------


class DatabankProcess:
    """The real databank service in a subprocess, connected to the test hub."""

    def __init__(self, endpoint: str, watcher: zenoh.Session, args: Sequence[str] = ()) -> None:
        self.endpoint = endpoint
        self.watcher = watcher
        self.args = list(args)
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        # its log goes to a file: a pipe nobody reads would stall a databank that logs 64 KB
        # over a test session, and the file says what it did when it does not come up
        with awaiting_token(self.watcher, KEYS.alive_databank_all()) as up, \
                tempfile.TemporaryFile() as log:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "kinesphere.cli", "databank", "serve",
                 "--connect", self.endpoint, "--listen", zconfig.LOOPBACK_ANY_PORT, *self.args],
                cwd=ROOT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
                stdout=subprocess.DEVNULL, stderr=log,
            )
            if not up.wait(WAIT_S):
                running = self.proc.poll() is None
                self.stop()
                log.seek(0)
                said = log.read().decode(errors="replace")[-2000:] or "nothing"
                raise RuntimeError(
                    f"databank did not declare its liveliness token within {WAIT_S:g} s "
                    f"({'still running' if running else 'it had exited'}); it logged: {said}")

    def stop(self) -> None:
        if self.proc is None:
            return
        stop_process(self.proc, timeout=10)
        self.proc = None

    def query(self, platform: str, part: SpatialCommand) -> Pose:
        """Ask the databank directly (what the test expects the robot to reach)."""
        key = KEYS.pose(platform, part.limb, part.origin, part.direction, part.size)
        for reply in self.watcher.get(key, timeout=5.0):
            if reply.ok is not None:
                return decode(reply.ok.payload, Pose)
            assert reply.err is not None
            raise error_from_reply(reply.err.payload)
        raise RuntimeError(f"no databank answers {key}")

    def catalogue(self, platform: str) -> Catalogue:
        for reply in self.watcher.get(KEYS.catalogue(platform), timeout=5.0):
            assert reply.ok is not None, platform
            return decode(reply.ok.payload, Catalogue)
        raise RuntimeError(f"no catalogue for {platform}")


@contextmanager
def databank_on(hub: Hub) -> Iterator[DatabankProcess]:
    """The real databank process serving every shipped platform on ``hub``, started and
    stopped around the block."""
    bank = DatabankProcess(hub.endpoint, hub.session)
    bank.start()
    try:
        yield bank
    finally:
        bank.stop()


def robots_alive(alive: Alive, pred: Callable[[set[str]], bool], what: str) -> set[str]:
    """The robots whose liveliness tokens ``alive`` (:func:`kinesphere.deploy.watch.watch_alive`)
    sees, once ``pred`` holds of them; fails naming ``what`` after :data:`WAIT_S`."""
    assert alive.wait_for(lambda a: pred(a.robots), WAIT_S), f"{what}: alive {sorted(alive.robots)}"
    with alive.changed:
        return set(alive.robots)


# --- robots ------------------------------------------------------------------------------------


@dataclass
class Trace:
    """The Ruckig outputs and the simulated joints at every control step."""

    t: list[float] = field(default_factory=list)
    pos: list[np.ndarray] = field(default_factory=list)
    vel: list[np.ndarray] = field(default_factory=list)
    acc: list[np.ndarray] = field(default_factory=list)
    sim: list[np.ndarray] = field(default_factory=list)
    base_vel: list[np.ndarray] = field(default_factory=list)

    def __call__(self, c: Controller) -> None:
        self.t.append(c.time)
        self.pos.append(c.joints.position.copy())
        self.vel.append(c.joints.velocity.copy())
        self.acc.append(c.joints.acceleration.copy())
        self.sim.append(np.array(c.q()))
        if c.base is not None:
            self.base_vel.append(c.base.twist.copy())

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return (np.array(self.t), np.array(self.pos), np.array(self.vel), np.array(self.acc))


class StateWatch(Watch[RobotState]):
    """The RobotState stream of one robot, with waits on predicates."""

    def __init__(self, session: zenoh.Session, robot_id: str) -> None:
        super().__init__(session, KEYS.state(robot_id), RobotState)
        self.states = self.heard

    def wait(self, pred: Callable[[RobotState], bool], what: str, timeout: float = WAIT_S,
             *, start: int = -1) -> RobotState:
        """The first state from now on (or the latest) satisfying ``pred``."""
        return super().wait(pred, what, timeout, start=start)

    def after(self, seq: int, pred: Callable[[RobotState], bool], what: str,
              timeout: float = WAIT_S) -> RobotState:
        """A state acting on command ``seq`` (or later) that satisfies ``pred``."""
        return self.wait(lambda s: s.last_command_seq >= seq and pred(s), what, timeout)


class AgentOverrides(TypedDict, total=False):
    """The :class:`AgentOptions` a test sets besides ``speed``."""

    control_rate: float
    body: str
    ros2: Ros2BodyOptions
    groups: tuple[str, ...]
    max_translation_m: float


@contextmanager
def running_agent(
    endpoint: str, platform: str, robot_id: str | None = None, speed: float = 0.0,
    trace: Trace | None = None, own_body: Body | None = None,
    **options: Unpack[AgentOverrides],
) -> Iterator[tuple[Agent, StateWatch]]:
    """An agent in this process with its own session joined to the hub, and its state;
    ``own_body`` is a body object it drives instead of the one its options make."""
    robot_id = robot_id or Path(platform).name
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        agent = Agent(platform, robot_id, s, AgentOptions(speed=speed, **options), body=own_body)
        if trace is not None:
            agent.controller.on_step = trace
        with StateWatch(s, robot_id) as watch, agent:
            watch.wait(lambda st: True, f"first state of {robot_id}")
            yield agent, watch


@contextmanager
def agent_process(endpoint: str, platform: str, robot_id: str) -> Iterator[subprocess.Popen[bytes]]:
    """``kinesphere agent`` as a process of its own joined to the hub (a test may freeze it
    with SIGSTOP); thawed and stopped on exit, killed if it does not stop."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "kinesphere.cli", "agent", platform, "--id", robot_id,
         "--connect", endpoint, "--listen", zconfig.LOOPBACK_ANY_PORT],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        yield proc
    finally:
        stop_process(proc)


@contextmanager
def running_fleet_host(endpoint: str, robots: list[RobotSpec], speed: float = 2.0,
                       query_timeout_s: float = AgentOptions.query_timeout_s,
                       ) -> Iterator[tuple[FleetHost, dict[str, StateWatch]]]:
    """A fleet host in this process on its own session, and each robot's state stream;
    ``query_timeout_s`` bounds the robots' databank queries (a nested solve waits at least
    ``SOLVE_TIMEOUT_S``)."""
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        fleet = FleetHost(robots, s, AgentOptions(speed=speed, query_timeout_s=query_timeout_s),
                          helpers=1)
        watches = {r.robot_id: StateWatch(s, r.robot_id) for r in robots}
        fleet.start()
        try:
            for rid, w in watches.items():
                w.wait(lambda st: True, f"first state of {rid}")
            yield fleet, watches
        finally:
            fleet.close()
            for w in watches.values():
                w.close()


def knows(s: zenoh.Session, robot_id: str) -> None:
    """Wait until ``s`` knows ``robot_id``'s command subscriber, so a fleet command put from
    ``s`` reaches that robot (its own session hearing its first state says nothing of ``s``)."""
    probe = s.declare_publisher(KEYS.command(robot_id))
    try:
        assert zconfig.wait_matching(probe, WAIT_S), f"{robot_id} unknown to the sender"
    finally:
        zconfig.undeclare(probe)


class CommandSender(Closable):
    """A client putting Commands, as the gamepad client would (``session`` "" is a version-1
    client's): on publishers like ``RobotLink.publisher``'s, never dropped under congestion
    (BLOCK), express, e-stops at REAL_TIME priority and the rest at INTERACTIVE_HIGH. Its first
    put waits for a subscriber to match (up to ``WAIT_S``, else the test fails): made before
    its robot starts, it waits for that robot there, not for nobody when made. A sender to
    ``*`` matches as soon as one robot's subscriber is known: a test whose first put must reach
    several waits with :func:`knows` for each. Used as ``with``, its publishers are undeclared
    even when the block fails."""

    def __init__(self, session: zenoh.Session, robot_id: str = "*", sender: str = "test",
                 key: str | None = None, client_session: str = "") -> None:
        key = key or KEYS.command(robot_id)
        self.pub, self.urgent = (session.declare_publisher(
            key, congestion_control=zenoh.CongestionControl.BLOCK, priority=priority,
            express=True) for priority in (zenoh.Priority.INTERACTIVE_HIGH,
                                           zenoh.Priority.REAL_TIME))
        self.sender = sender
        self.session = client_session
        self.seq = 0
        self._matched = False

    def send(self, *parts: Part | SpatialCommand,
             drive: tuple[str, float] | Drive | None = None,
             deadman: bool = True, ttl_ms: int = 0, estop: bool = False,
             stop: bool = False, release: bool = False, lease: str = "",
             seq: int | None = None, sent_ns: int | None = None) -> int:
        self.seq = self.seq + 1 if seq is None else seq
        if isinstance(drive, tuple):
            drive = Drive(*drive)
        self._match()
        (self.urgent if estop else self.pub).put(encode(Command(
            seq=self.seq, sent_ns=time.time_ns() if sent_ns is None else sent_ns,
            parts=[p if isinstance(p, SpatialCommand) else SpatialCommand(*p) for p in parts],
            drive=drive, deadman=deadman, ttl_ms=ttl_ms, estop=estop, stop=stop,
            release=release, sender=self.sender, session=self.session,
            lease=LeaseAction(lease))))
        return self.seq

    def raw(self, payload: bytes) -> None:
        self._match()
        self.pub.put(payload)

    def _match(self) -> None:
        if not self._matched:
            self._matched = True
            assert zconfig.wait_matching(self.pub, WAIT_S), "no robot subscribes to the key"

    def close(self) -> None:
        zconfig.undeclare(self.pub, self.urgent)


class AckWatch(Watch[Ack]):
    """The Acks of one robot (``*``: all), with waits on predicates."""

    def __init__(self, session: zenoh.Session, robot_id: str = "*") -> None:
        super().__init__(session, KEYS.ack(robot_id), Ack)
        self.acks = self.heard

    def of(self, sender: str, seq: int, stage: str, what: str = "") -> Ack:
        return self.wait(lambda a: a.sender == sender and a.seq == seq and a.stage == stage,
                         what or f"{stage} for {sender} #{seq}")

    def stages(self, sender: str, seq: int) -> list[str]:
        with self._cond:
            return [a.stage for a in self.acks if a.sender == sender and a.seq == seq]


def newer_than(seq: int, state: RobotState) -> bool:
    """``state`` comes after the robot's state number ``seq`` (for waits: ``partial(newer_than,
    seq)``)."""
    return state.seq > seq


def real_pulls(entry: LimbEntry) -> list[str]:
    """The directions of a catalogue entry that pull somewhere: all but place-middle (the
    limb's neutral pose)."""
    return [d for d in entry.directions if d != "place-middle"]


def horizontal_pulls(entry: LimbEntry) -> list[str]:
    """The directions of a catalogue entry with a horizontal part (every place-* left out)."""
    return [d for d in entry.directions if Direction.parse(d).horizontal.name != "PLACE"]


def far(cat: Catalogue, k: int = 0, *, horizontal: bool = False, past: float = 0.0) -> Part:
    """The far reach of the first limb in its ``k``-th real pull (place-middle left out), or
    with ``horizontal`` its ``k``-th pull with a horizontal part (every place-* left out);
    ``past`` sizes beyond far, where a mobile base translates the excess."""
    entry = cat.limbs[0]
    pulls = horizontal_pulls(entry) if horizontal else real_pulls(entry)
    return (entry.limb, entry.origin, pulls[k], float(max(entry.sizes)) + past)


def joints_close(state: RobotState, joints: Mapping[str, float], tol: float) -> bool:
    q = dict(zip(state.joint_names, state.q, strict=True))
    return all(abs(q[j] - v) <= tol for j, v in joints.items())


Part = tuple[str, str, str, float]
"""One spatial command's words (limb, origin, direction, size), as :func:`far` gives them."""


@dataclass
class HeldAgent:
    """A real Baxter agent process that sender "ann" took to a first far target and that is
    held there, for a test that freezes it (SIGSTOP) while commands arrive and thaws it."""

    proc: subprocess.Popen[bytes]
    watch: StateWatch
    acks: AckWatch
    state: RobotState
    """The state that reported the first target reached."""
    there: Part
    """A second far target (the limb's last pull)."""

    def freeze(self) -> None:
        self.proc.send_signal(signal.SIGSTOP)

    def thaw(self) -> int:
        """Let the process run again; how many states were heard before."""
        seen = len(self.watch.states)
        self.proc.send_signal(signal.SIGCONT)
        return seen

    def moved_after(self, seen: int) -> tuple[RobotState, float]:
        """After 1.5 s of states since the thaw: the latest, and how far (rad) any joint
        moved from the first target meanwhile."""
        after = self.watch.wait(lambda s: len(self.watch.states) > seen + 75,
                                "1.5 s of states after")
        before = np.array(self.state.q)
        moved = max(float(np.abs(np.array(s.q) - before).max())
                    for s in self.watch.states[seen:])
        return after, moved


@contextmanager
def held_agent(hub: Hub, databank: DatabankProcess, robot_id: str,
               send: Callable[[Part], int]) -> Iterator[HeldAgent]:
    """:func:`agent_process` of Baxter as ``robot_id``, taken to the far reach of its first
    limb's first pull by ``send`` (put ann's command toward the part, return its seq), sent
    again until the robot acknowledges it reached; its watches closed on exit."""
    session, endpoint = hub
    cat = databank.catalogue("baxter")
    here = far(cat, 0)
    pose = databank.query("baxter", SpatialCommand(*here))
    with (StateWatch(session, robot_id) as watch, AckWatch(session, robot_id) as acks,
          agent_process(endpoint, "baxter", robot_id) as proc):
        watch.wait(lambda s: True, "the agent is up")
        while True:
            seq = send(here)
            state = watch.after(seq, lambda s: True, "a state")
            if "reached" in acks.stages("ann", seq):
                break
        assert joints_close(state, pose.joints, 0.02)
        yield HeldAgent(proc, watch, acks, state, far(cat, -1))


def finite_jerk(trace: Trace) -> tuple[np.ndarray, np.ndarray]:
    """Jerk and velocity steps from finite differences of the Ruckig outputs."""
    t, _, vel, acc = trace.arrays()
    dt = np.diff(t)[:, None]
    return np.abs(np.diff(acc, axis=0) / dt), np.abs(np.diff(vel, axis=0))


def overlap(trace: Trace) -> tuple[float, float]:
    """Robot-time spans (start, end) where joints and base both move."""
    t = np.array(trace.t)
    joints = np.abs(np.array(trace.vel)).max(axis=1) > 1e-3
    base = np.hypot(*np.array(trace.base_vel)[:, :2].T) > 1e-3
    both = t[joints & base]
    return (float(both.min()), float(both.max())) if both.size else (math.nan, math.nan)
