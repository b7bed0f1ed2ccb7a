"""What the view knows about every robot, fed by Zenoh: states, liveliness, commands, acks.

Zenoh callbacks only decode and store under a lock; the view's frame loop takes a
:meth:`Fleet.snapshot` when it draws. Commands are attributed to the robots they reach: a
robot's own key, the all-robots key, or a group key (robots whose state lists that group).
Everything is bounded: at most :data:`MAX_ROBOTS` robots are tracked, whatever ids a peer
invents, and a robot without a liveliness token is forgotten.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field, replace
from typing import Any, Final

import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import WILDCARD, Keys
from kinesphere.protocol import Ack, Command, RobotState, decode
from kinesphere.zconfig import undeclare

log = logging.getLogger(__name__)
MAX_ROBOTS: Final = 256


@dataclass(frozen=True)
class Robot:
    """One robot as the view sees it now."""

    robot_id: str
    alive: bool = False
    state: RobotState | None = None
    state_at: float = 0.0
    """Monotonic seconds when the state arrived."""
    command: Command | None = None
    """The newest command that reached this robot."""
    motion: Command | None = None
    """The newest command with parts (the target), None after a stop, e-stop or let-go."""
    ack: Ack | None = None


@dataclass
class _Table:
    robots: dict[str, Robot] = field(default_factory=dict)
    version: int = 0


class Fleet:
    """Watches every robot under ``keys.prefix`` on ``session`` until :meth:`close`."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.keys = keys
        self._n = keys.prefix.count("/") + 1
        self._lock = threading.Lock()
        self._table = _Table()
        self.changed = threading.Event()
        """Set on every change; the frame loop clears it when it draws."""
        self._entities: list[Any] = [
            session.declare_subscriber(keys.state(WILDCARD), self._on_state),
            session.declare_subscriber(keys.ack(WILDCARD), self._on_ack),
            session.declare_subscriber(Keys.subscribed(keys.command(WILDCARD)),
                                       self._on_command),
            session.declare_subscriber(Keys.subscribed(f"{keys.prefix}/group/*/command"),
                                       self._on_command),
            session.liveliness().declare_subscriber(keys.alive_robot(WILDCARD), self._on_alive,
                                                    history=True),
        ]

    def snapshot(self) -> dict[str, Robot]:
        """Every robot that holds a liveliness token, by id."""
        with self._lock:
            return {rid: r for rid, r in self._table.robots.items() if r.alive}

    def close(self) -> None:
        undeclare(*self._entities)
        self._entities.clear()

    # --- Zenoh callbacks -------------------------------------------------------------------

    def _update(self, robot_id: str, create: bool = False, **changes: Any) -> None:
        with self._lock:
            robots = self._table.robots
            robot = robots.get(robot_id)
            if robot is None:
                if not create or len(robots) >= MAX_ROBOTS:
                    return
                robot = Robot(robot_id)
            robots[robot_id] = replace(robot, **changes)
            self._table.version += 1
        self.changed.set()

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            rid = self.keys.robot_id_of(str(sample.key_expr))
        except KinesphereError:
            return
        if sample.kind == zenoh.SampleKind.DELETE:
            with self._lock:
                self._table.robots.pop(rid, None)
            self.changed.set()
        else:
            self._update(rid, create=True, alive=True)

    def _on_state(self, sample: zenoh.Sample) -> None:
        try:
            st = decode(sample.payload, RobotState)
            rid = self.keys.robot_id_of(str(sample.key_expr))
        except KinesphereError as exc:
            log.debug("ignoring state on %s: %s", sample.key_expr, exc)
            return
        if st.robot_id == rid:  # a state must come from the robot whose key it is on
            self._update(rid, state=st, state_at=time.monotonic())

    def _on_ack(self, sample: zenoh.Sample) -> None:
        try:
            ack = decode(sample.payload, Ack)
            rid = self.keys.robot_id_of(str(sample.key_expr))
        except KinesphereError:
            return
        self._update(rid, ack=ack)

    def _on_command(self, sample: zenoh.Sample) -> None:
        try:
            cmd = decode(sample.payload, Command)
        except KinesphereError:
            return
        for rid in self._addressed(str(sample.key_expr)):
            changes: dict[str, Any] = {"command": cmd}
            if cmd.parts and cmd.deadman and not (cmd.stop or cmd.estop or cmd.release):
                changes["motion"] = cmd
            elif cmd.stop or cmd.estop or not cmd.deadman:
                changes["motion"] = None
            self._update(rid, **changes)

    def _addressed(self, key: str) -> list[str]:
        """Robot ids a command key reaches (only robots already known)."""
        rest = key.split("/")[self._n:]  # .../command, or .../command/<sender>
        with self._lock:
            robots = self._table.robots
            if len(rest) in (3, 4) and rest[0] == "robot" and rest[2] == "command":
                return list(robots) if rest[1] == WILDCARD else [rest[1]]
            if len(rest) in (3, 4) and rest[0] == "group" and rest[2] == "command":
                return [rid for rid, r in robots.items()
                        if r.state is not None and rest[1] in r.state.groups]
        return []
