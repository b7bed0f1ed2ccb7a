"""A fleet host: many robots in one process, one control loop stepping every body per tick.

Why: a simulated robot at 500 Hz costs 20-60 us of work per step, but as a process of its own
it also pays an interpreter, a Zenoh session and a scheduler wake-up every 2 ms; on two cores
that kept 16 robots in real time. A fleet host runs one :class:`Agent` per robot on one Zenoh
session, and each robot keeps everything that makes it a robot: its keys, liveliness token,
state stream, acks, lease, watchdog, e-stop latch and databank resolver. Per tick the loop
does every robot's commands and trajectories and hands the setpoints to the bodies; then the
bodies' physics (with their hard stops) is split between the loop's thread and helper threads
(``stepper.py``: MuJoCo releases the GIL, so the shares step side by side). The loop returns
once its own share is done; the helpers' shares finish while it waits for its next tick, which
begins with every robot's faults, acks and state. So physics overlaps physics and the loop's
idle time, and a helper that starts late under load costs the loop nothing unless it is still
busy a whole period later. Robots publish state on different ticks (``phase``), so no tick
encodes them all. Whatever arrives for any robot wakes the loop at once (``pacing.py``); a
robot whose step fails is held and reported alone.

Robots come from ``kinesphere fleet FLEET.toml`` (:func:`load_fleet_file`) or repeated
``kinesphere agent --robot PLATFORM:ID`` (:func:`parse_robot`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import msgspec
import zenoh

from kinesphere.configfile import load_toml
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import check_segment
from kinesphere.protocol import Status
from kinesphere.robots.agent.options import AgentOptions
from kinesphere.robots.agent.pacing import LoopStats, Wake, run_paced
from kinesphere.robots.agent.runtime import Agent
from kinesphere.robots.agent.stepper import Stepper

log = logging.getLogger(__name__)

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


class FleetHost:
    """Robots stepped together by one loop (module text); ``options`` apply to every robot
    (each robot's groups come from its :class:`RobotSpec`). ``helpers``: physics threads
    beside the loop's own (None: one per further core)."""

    def __init__(self, robots: Sequence[RobotSpec], session: zenoh.Session,
                 options: AgentOptions | None = None, helpers: int | None = None) -> None:
        check_fleet(robots)
        self.options = options or AgentOptions()
        if self.options.body != "mujoco":
            raise KinesphereError("malformed", f"a fleet host runs simulated bodies (--body "
                                  f"mujoco), not {self.options.body!r}: run one agent per "
                                  "real robot")
        self.wake = Wake()
        self.stats = LoopStats()
        self.agents: list[Agent] = []
        try:
            for i, r in enumerate(robots):
                self.agents.append(Agent(r.platform, r.robot_id, session,
                                         replace(self.options, groups=r.groups),
                                         wake=self.wake, phase=i))
        except BaseException:
            self._close_agents()
            raise
        self.stepper = Stepper(helpers)
        self._failures: list[Exception | None] | None = None
        """The step in flight (its physics launched): what failed before the physics."""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def declare(self) -> None:
        """Every robot's subscriptions, publishers and liveliness token."""
        for agent in self.agents:
            agent.declare()
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
        period = 1.0 / o.rate / o.speed if o.speed > 0 else 0.0

        def stopped() -> bool:
            return self._stop.is_set() or (stop is not None and stop.is_set())

        def failed(exc: Exception) -> None:  # a bug in the loop itself: every robot says so
            for agent in self.agents:
                agent.conduct.set(Status.ERROR, f"internal: fleet step failed: {exc!r}")

        wake = None if o.strict_period else self.wake
        run_paced(self.tick, period, stopped, self.stats, "fleet host", failed, wake)

    def tick(self) -> None:
        """One control cycle of every robot (module text): the end of the last tick's step,
        then this tick's commands and trajectories, then the physics: this thread's share now,
        the helpers' finishing while the loop waits for its next tick."""
        self.complete()
        failures = [_guarded(a.begin_step) for a in self.agents]
        self._failures = failures
        bodies = [a.controller.body for a, f in zip(self.agents, failures, strict=True)
                  if f is None]
        self.stepper.launch(bodies, share=True)
        self.stats.steps += 1

    def complete(self) -> None:
        """Finish the step in flight: wait for its physics, then every robot's faults, acks
        and state (a no-op when none is)."""
        failures, self._failures = self._failures, None
        if failures is None:
            return
        errors = iter(self.stepper.wait())
        for agent, failure in zip(self.agents, failures, strict=True):
            if failure is None:
                failure = next(errors)
            try:
                agent.end_step(failure)
            except Exception:  # one robot's bug must not hold up the others
                log.exception("fleet host: robot %s: end of step failed", agent.robot_id)

    def close(self) -> None:
        """Stop the loop and every robot (the session stays open: the caller owns it)."""
        self._stop.set()
        self.wake.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self.complete()
        self.stepper.close()
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

    def __enter__(self) -> FleetHost:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


def _guarded(call: Callable[[], Exception | None]) -> Exception | None:
    """``call()``'s own result, or what it raised."""
    try:
        return call()
    except Exception as exc:
        return exc
