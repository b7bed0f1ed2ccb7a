"""A fleet host: many robots in one process, one control loop stepping every body per tick.

Why: a simulated robot at 500 Hz costs 20-60 us of work per step, but as a process of its own
it also pays an interpreter, a Zenoh session and a scheduler wake-up every 2 ms. A fleet host
runs one :class:`Agent` per robot on one Zenoh session, and each robot keeps everything that
makes it a robot: its keys, liveliness token, state stream, acks, lease, watchdog, e-stop
latch and databank resolver. ``kinesphere fleet`` runs one fleet host per core, each with a
share of the robots (``workers.py``).

Per tick, what every robot does every step is done for all of them at once: their joint
trajectories are followed on arrays (``follow.py``: Ruckig plans, the arrays take the steps
between plans), the hard stops of all bodies are one comparison (``HardStops``), and the
robots whose state is due are looked up, not asked: they publish in groups (``state_steps``),
each group's states composed first and then put back to back, so Zenoh sends them in one
batch. A robot runs its whole cycle (e-stops and
commands, timers, the guard's verdicts, what it says) only when something is there for it:
something arrived (its inbox and guard ``notify`` the host), a timer runs out
(``Conduct.deadline``), a motion's ``moving`` is to say. Otherwise it only moves
(``Agent.follow``: the followed setpoint to its body, its base's step) or, at rest, nothing at
all but its physics. A robot whose motion is the followers' alone glides
(``Controller.glides``): the loop copies the followers' output to its body's servo targets
itself, with no call into the robot before the physics (a moving base's step is one call, its
integration of what the followers did: the glide rolls). After the physics, the glides of all
robots with nothing else to watch (``Agent.ledgered``) end at once: one array operation counts
their robot time and notes that they moved (``ledger.py``); only a body that touches something
is looked at by its guard (``Agent.glided``). A robot whose step fails is held and reported
alone.

The physics of the bodies is split between the loop's thread and helper threads (``stepper.py``:
MuJoCo releases the GIL); the loop returns once its own share is done, and the helpers' shares
finish while it waits for its next tick, which begins with the end of the step: hard stops,
faults, acks, states. Whatever arrives for any robot wakes the loop at once (``pacing.py``).

Robots come from ``kinesphere fleet FLEET.toml`` (:func:`load_fleet_file`) or repeated
``kinesphere agent --robot PLATFORM:ID`` (:func:`parse_robot`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import msgspec
import numpy as np
import zenoh

from kinesphere.closing import Startable
from kinesphere.configfile import load_toml
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys, check_segment
from kinesphere.protocol import Status
from kinesphere.robots.agent.body import AT_REST, Body
from kinesphere.robots.agent.estops import FleetBoard
from kinesphere.robots.agent.follow import Followers
from kinesphere.robots.agent.inbox import clocks
from kinesphere.robots.agent.ledger import Ledger
from kinesphere.robots.agent.mujoco_body import HardStops, MujocoBody
from kinesphere.robots.agent.options import AgentOptions
from kinesphere.robots.agent.pacing import LoopStats, Wake, run_paced
from kinesphere.robots.agent.runtime import Agent
from kinesphere.robots.agent.stepper import Stepper

log = logging.getLogger(__name__)

_CYCLE, _LEAN, _GLIDE, _ROLL, _REST = object(), object(), object(), object(), object()
"""What a robot does in a tick: the whole cycle, only its motion (``Agent.follow``), only the
followers' setpoint to its body (``Controller.glides``, ``Agent.glided``), that and its moving
base's step (a glide that rolls), or nothing but robot time (``Fleet.tick``)."""
_KINDS = {_CYCLE: "cycle", _LEAN: "lean", _GLIDE: "glide", _ROLL: "glide", _REST: "rest"}

STATE_BURST = 16
"""Robots whose states a fleet host publishes in the same step, at most (``state_steps``)."""
MAX_ROBOTS = 1024
"""Robots one fleet host runs (each holds a MuJoCo model instance and a resolver thread)."""


@dataclass(frozen=True)
class RobotSpec:
    """One robot of a fleet: its platform (a shipped name or a folder), id and groups."""

    platform: str
    robot_id: str
    groups: tuple[str, ...] = ()


def parse_robot(text: str) -> RobotSpec:
    """``PLATFORM:ID`` (or ``PLATFORM``: the id is the platform's name), as ``--robot`` takes."""
    platform, sep, robot_id = text.rpartition(":")
    if not sep:
        platform, robot_id = text, Path(text).name
    if not platform or not robot_id:
        raise KinesphereError("malformed", f"--robot {text!r}: expected PLATFORM:ID, e.g. "
                              "baxter:baxter-1")
    return RobotSpec(platform, robot_id)


class _FleetRobot(msgspec.Struct, forbid_unknown_fields=True):
    platform: str
    groups: list[str] = []


class _FleetFile(msgspec.Struct, forbid_unknown_fields=True):
    robots: dict[str, _FleetRobot]
    prefix: str | None = None


def load_fleet_file(path: Path) -> tuple[list[RobotSpec], str | None]:
    """The robots of a fleet file (TOML) and its key prefix (None when it names none)::

        prefix = "kinesphere"          # optional
        [robots.baxter-1]
        platform = "baxter"
        groups = ["arms"]              # optional
    """
    data = load_toml(path, _FleetFile, "fleet file")
    robots = [RobotSpec(r.platform, rid, tuple(r.groups)) for rid, r in data.robots.items()]
    return robots, data.prefix


def check_fleet(robots: Sequence[RobotSpec]) -> None:
    """At least one robot, at most :data:`MAX_ROBOTS`, ids and groups valid and ids unique."""
    if not robots:
        raise KinesphereError("malformed", "a fleet needs at least one robot")
    if len(robots) > MAX_ROBOTS:
        raise KinesphereError("malformed", f"{len(robots)} robots; a fleet host runs at most "
                              f"{MAX_ROBOTS}")
    seen: set[str] = set()
    for r in robots:
        check_segment(r.robot_id, "robot id")
        for group in r.groups:
            check_segment(group, f"group of {r.robot_id}")
        if r.robot_id in seen:
            raise KinesphereError("malformed", f"robot id {r.robot_id!r} appears twice")
        seen.add(r.robot_id)


class FleetHost(Startable):
    """Robots stepped together by one loop (module text); ``options`` apply to every robot
    (each robot's groups come from its :class:`RobotSpec`). ``helpers``: physics threads
    beside the loop's own (None: one per further core)."""

    def __init__(self, robots: Sequence[RobotSpec], session: zenoh.Session,
                 options: AgentOptions | None = None, helpers: int | None = None,
                 batched: bool = True) -> None:
        check_fleet(robots)
        self.options = options or AgentOptions()
        if self.options.body != "mujoco":
            raise KinesphereError("malformed", f"a fleet host runs simulated bodies (--body "
                                  f"mujoco), not {self.options.body!r}: run one agent per "
                                  "real robot")
        self.wake = Wake()
        self.stats = LoopStats()
        self._awake: deque[int] = deque()
        """Robots something arrived for (any thread): the whole cycle next step."""
        self.board = FleetBoard(session, Keys(self.options.prefix))
        """The fleet e-stops in force, one board for every robot of the process."""
        self.ledger = Ledger(len(robots), 1.0 / self.options.control_rate)
        """Every robot's robot time and when it last moved (``ledger.py``)."""
        self.agents: list[Agent] = []
        every = self.options.publish_every
        steps = state_steps(len(robots), every, STATE_BURST)
        try:
            for i, r in enumerate(robots):
                self.agents.append(Agent(r.platform, r.robot_id, session,
                                         replace(self.options, groups=r.groups),
                                         wake=self.wake, phase=-steps[i] % every,
                                         stats=self.stats,
                                         notify=self._notify(i), board=self.board,
                                         ledger=self.ledger, slot=i))
        except BaseException:
            self._close_agents()
            raise
        self.stepper = Stepper(helpers)
        self.batched = batched
        """False: every robot's whole cycle every step, Ruckig stepped per robot (the way
        before the batching, kept to measure it against: ``bench_fleet.py``)."""
        self.followers = Followers([g for a in self.agents for g in a.controller.generators]
                                   if batched else [], 1.0 / self.options.control_rate)
        self._bodies: list[Body] = []
        self._commands: list[Callable[[np.ndarray, Sequence[float] | np.ndarray], None]] = []
        self._setpoints: list[np.ndarray | None] = []
        """Each body's joint servo targets as a view (``MujocoBody.joint_setpoints``), or None:
        a gliding robot's setpoint is copied there, else handed to ``command``."""
        self._datas: list[object] = []
        """Each body's MjData (None for a body that is not MuJoCo's): whether it touches."""
        self._stops = HardStops([])
        self._due: list[list[Agent]] = [[] for _ in range(every)]
        """Robots whose state is due, by tick modulo the state period (``Agent.due``)."""
        for agent in self.agents:
            self._due[(-agent.phase) % every].append(agent)
        self._joints = [a.controller.joints.generator for a in self.agents]
        """Each robot's joint generator (a gliding robot's setpoint is its followed output)."""
        self._bases = [a.controller.base for a in self.agents]
        """Each robot's base controller (None: a fixed base): a rolling glide steps it."""
        self._modes: list[object] = [_CYCLE] * len(self.agents)
        """What each robot does in the step in flight (:meth:`tick`), then in the next."""
        self._ledgered = [False] * len(self.agents)
        """Gliding robots whose end of step is the ledger's alone (``Agent.ledgered``): robot
        time and "it moved" noted for all of them at once, unless a body touches."""
        self._deadlines = np.full(len(self.agents), np.inf)
        """When each robot's next timer runs out (``Conduct.deadline``; monotonic s)."""
        self._failures: list[Exception | None] | None = None
        """The step in flight (its physics launched): what failed before the physics."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def declare(self) -> None:
        """The fleet e-stops in force, then every robot's id, subscriptions, publishers and
        liveliness token (``id_taken`` when another agent runs one of the ids)."""
        self.board.declare()
        self.board.sync()
        for agent in self.agents:
            agent.declare()
        self.board.start()
        log.info("fleet host up: %d robots, %d physics threads", len(self.agents),
                 self.stepper.threads)

    def start(self) -> FleetHost:
        """Declare and run the loop in a thread; :meth:`close` ends both."""
        self.declare()
        self._thread = threading.Thread(target=self.run, name="fleet", daemon=True)
        self._thread.start()
        return self

    def run(self, stop: threading.Event | None = None) -> None:
        """Tick paced by ``options.speed`` until :meth:`close` (or ``stop`` is set)."""
        o = self.options
        period = 1.0 / o.control_rate / o.speed if o.speed > 0 else 0.0

        def stopped() -> bool:
            return self._stop.is_set() or (stop is not None and stop.is_set())

        def failed(exc: Exception) -> None:  # a bug in the loop itself: every robot says so
            for agent in self.agents:
                agent.conduct.set(Status.ERROR, f"internal: fleet step failed: {exc!r}")

        wake = None if o.strict_period else self.wake
        run_paced(self.tick, period, stopped, self.stats, "fleet host", failed, wake)

    def tick(self) -> None:
        """One control cycle of every robot (module text): the end of the last tick's step,
        then this tick's commands, the trajectories followed at once, each robot's
        setpoints, then the physics: this thread's share now, the helpers' finishing while the
        loop waits for its next tick. A robot with nothing to react to (``Agent.needs_cycle``)
        only hands its followed setpoint to its body, or nothing at all when it is at rest."""
        self.complete()
        agents, modes, awake = self.agents, self._modes, self._awake
        ledgered = self._ledgered
        while awake:
            i = awake.popleft()
            modes[i], ledgered[i] = _CYCLE, False
        now_ns = clocks()[0]
        self.stats.begin(now_ns)
        deadlines = self._deadlines
        for i in (deadlines <= now_ns / 1e9).nonzero()[0].tolist():
            modes[i], ledgered[i] = _CYCLE, False
            deadlines[i] = np.inf
        bodies = [a.controller.body for a in agents]
        if bodies != self._bodies:
            self._regroup(bodies)
        bodies = self._bodies  # the same list each tick: the stepper keeps what it made of it
        failures: list[Exception | None] = [None] * len(agents)
        cycling = [i for i, mode in enumerate(modes) if mode is _CYCLE]
        for i in cycling:
            failures[i] = _guarded(agents[i].react)
        self.followers.advance()
        for i in cycling:
            if failures[i] is None:
                failures[i] = _guarded(agents[i].actuate)
        joints, commands, setpoints = self._joints, self._commands, self._setpoints
        bases = self._bases
        for i, mode in enumerate(modes):
            if mode is _GLIDE:
                otg = joints[i]
                if otg.following:  # the followers took the step: their output is the setpoint
                    servo = setpoints[i]
                    try:
                        if servo is not None:
                            servo[:] = otg.position
                        else:
                            commands[i](otg.position, AT_REST)
                    except Exception as exc:  # reported for this robot; the others step on
                        failures[i] = exc
                    continue
                mode = modes[i] = _LEAN  # the followers' step ended the motion: a lean step
                ledgered[i] = False
            elif mode is _ROLL:  # a glide whose base moves too: the base integrates its step
                otg, base = joints[i], bases[i]
                assert base is not None
                if base.generator.following and (
                        otg.following or not (otg.active or otg.came_to_rest)):
                    try:
                        base.step()
                        commands[i](otg.position, base.body_twist)
                    except Exception as exc:  # reported for this robot; the others step on
                        failures[i] = exc
                    continue
                mode = modes[i] = _LEAN
                ledgered[i] = False
            if mode is _LEAN:
                failures[i] = agents[i].follow()
        self._failures = failures
        self.stepper.launch(bodies if not any(failures) else
                            [b for b, f in zip(bodies, failures, strict=True) if f is None],
                            share=True)
        self.stats.steps += 1

    def complete(self) -> None:
        """Finish the step in flight: wait for its physics, the hard stops of every body at
        once, then every robot's faults and acks and what it does next step, and the states
        due (a no-op when no step is in flight)."""
        failures, self._failures = self._failures, None
        if failures is None:
            return
        errors = self.stepper.wait()
        if any(failures):  # the bodies stepped were those that had not failed before
            stepped = iter(errors)
            failures = [f if f is not None else next(stepped) for f in failures]
        else:
            failures = errors
        self._stops.apply()
        modes, ledgered = self._modes, self._ledgered
        if any(ledgered):  # their glides end at once, unless a body touches (the guard looks)
            datas = self._datas
            for i, flag in enumerate(ledgered):
                data = datas[i]  # a body that is not MuJoCo's is watched by its guard
                if flag and (failures[i] is not None or data is None
                             or data.ncon):  # type: ignore[attr-defined]
                    ledgered[i] = False
            self.ledger.glided(np.array(ledgered), time.monotonic())
        for i, (agent, failure) in enumerate(zip(self.agents, failures, strict=True)):
            if ledgered[i]:
                continue  # still gliding: the followers' next step says otherwise (tick)
            mode = modes[i]
            try:
                if failure is not None or mode is _CYCLE:
                    agent.end_step(failure)
                    mode = modes[i] = self._next(i, agent)
                elif mode is _GLIDE or mode is _ROLL:
                    if not agent.glided():
                        mode = modes[i] = self._next(i, agent)
                elif mode is _LEAN:
                    if not agent.followed():
                        mode = modes[i] = self._next(i, agent)
                    elif agent.controller.glides:
                        mode = modes[i] = self._glide(i)
                else:
                    agent.controller.elapse()
                ledgered[i] = ((mode is _GLIDE or mode is _ROLL) and self._datas[i] is not None
                               and agent.ledgered)
            except Exception:  # one robot's bug must not hold up the others
                log.exception("fleet host: robot %s: end of step failed", agent.robot_id)
                modes[i], ledgered[i] = _CYCLE, False
        due = self._due[self.stats.begun % len(self._due)]
        for agent in due:  # composed first, then put one after the other: one batch
            agent.compose_state()
        for agent in due:
            agent.put_state()

    def _next(self, i: int, agent: Agent) -> object:
        """What robot ``i`` does next step: the whole cycle, or follow its motion, or rest
        until something wakes it (``Agent.needs_cycle``)."""
        self._deadlines[i] = agent.conduct.deadline()
        if not self.batched or agent.needs_cycle():
            return _CYCLE
        if agent.at_rest:
            return _REST
        return self._glide(i) if agent.controller.glides else _LEAN

    def _glide(self, i: int) -> object:
        """A glide of robot ``i`` (``Controller.glides``): rolling when its base moves."""
        base = self._bases[i]
        return _ROLL if base is not None and base.stepping else _GLIDE

    def step_kind(self, i: int) -> str:
        """What robot ``i`` does in the step in flight (tests and tools): ``cycle``, ``lean``
        (``Agent.follow``), ``glide`` (the followers' setpoint only) or ``rest``."""
        return _KINDS[self._modes[i]]

    def ledgered(self, i: int) -> bool:
        """Whether robot ``i``'s glide in the step in flight ends by the ledger alone, with
        the other such robots' (tests and tools)."""
        return self._ledgered[i]

    def _notify(self, i: int) -> Callable[[], None]:
        """What robot ``i``'s inbox and guard call when something arrives for it (any
        thread): it does the whole cycle next step, which starts at once."""
        awake, wake = self._awake, self.wake

        def notify() -> None:
            awake.append(i)
            wake.set()

        return notify

    def _regroup(self, bodies: list[Body]) -> None:
        """The hard stops of the bodies stepped from now on, all at once, and their
        ``command`` (a gliding robot's setpoint goes straight to its body)."""
        self._bodies = bodies
        self._commands = [b.command for b in bodies]
        self._setpoints = [b.joint_setpoints() if isinstance(b, MujocoBody) else None
                           for b in bodies]
        self._datas = [b.data if isinstance(b, MujocoBody) else None for b in bodies]
        self._stops = HardStops([b for b in bodies if isinstance(b, MujocoBody)])
        self._ledgered[:] = [False] * len(bodies)  # each robot's own end of step, until
        # its next glide on the new bodies

    def close(self) -> None:
        """Stop the loop and every robot (the session stays open: the caller owns it)."""
        self._stop.set()
        self.wake.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self.complete()
        self.stepper.close()
        self.board.close()
        self._close_agents()
        s = self.stats
        costs = sorted(s.costs_s)
        p50, p99 = (costs[len(costs) // 2], costs[int(len(costs) * 0.99)]) if costs else (0, 0)
        log.info("fleet host down after %d ticks: %d late, %d slips, %d early; tick p50 %.2f ms, "
                 "p99 %.2f ms", s.steps, s.late, s.slips, s.early, p50 * 1e3, p99 * 1e3)

    def _close_agents(self) -> None:
        for agent in self.agents:
            try:
                agent.close()
            except Exception:
                log.exception("fleet host: closing robot %s failed", agent.robot_id)


def state_steps(robots: int, every: int, burst: int = STATE_BURST) -> list[int]:
    """The step of the state period (``every`` steps) in which each of ``robots`` robots
    publishes: in groups of at most ``burst`` robots, the groups spread evenly over the period.

    Why groups: Zenoh sends what is put back to back in one batch, one write and one wake-up of
    its transmit thread and of each subscriber's receiving thread, where states spread one or
    two per step cost a write and two wake-ups each: on loopback, measured between a sender and
    a subscriber process, 60-80 us of CPU per state put one at a time, 22-28 us per state put
    32 at a time (a worker's share of 32 robots at 500 Hz, interleaved in one run: its CPU
    0.91-0.93x, the subscriber's 0.50-0.54x the states put one by one). Why not all in one
    step: that step would compose every state (~20-30 us each) on top of its physics."""
    groups = min(every, -(-robots // max(1, burst)))
    return [(i * groups // robots) * every // groups for i in range(robots)]


def _guarded(call: Callable[[], Exception | None]) -> Exception | None:
    """``call()``'s own result, or what it raised."""
    try:
        return call()
    except Exception as exc:
        return exc
