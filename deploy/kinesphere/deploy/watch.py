"""Watch a running system over Zenoh: who is alive (liveliness) and what robots report (state).

Shared by ``kinesphere up``, ``kinesphere status`` and the system tests, which must wait on
events (a token appears, a state arrives) rather than sleep.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.protocol import RobotState, decode
from kinesphere.zconfig import undeclare


@dataclass
class Alive:
    """Live databank replicas and robots, kept current by a liveliness subscriber."""

    keys: Keys
    databanks: set[str] = field(default_factory=set)
    robots: set[str] = field(default_factory=set)
    changed: threading.Condition = field(default_factory=threading.Condition)

    def on_sample(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        present = sample.kind == zenoh.SampleKind.PUT
        with self.changed:
            try:
                if key.startswith(f"{self.keys.prefix}/alive/databank/"):
                    target, name = self.databanks, self.keys.replica_of(key)
                else:
                    target, name = self.robots, self.keys.robot_id_of(key)
            except KinesphereError:
                return
            if present:
                target.add(name)
            else:
                target.discard(name)
            self.changed.notify_all()

    def wait_for(self, pred: Callable[[Alive], bool], timeout: float) -> bool:
        """Wait until ``pred(self)`` holds; False when ``timeout`` seconds pass first."""
        with self.changed:
            return self.changed.wait_for(lambda: pred(self), timeout)


def watch_alive(session: zenoh.Session, keys: Keys) -> tuple[Alive, list[Any]]:
    """Subscribe (with history) to every databank and robot token; undeclare the list after."""
    alive = Alive(keys)
    lv = session.liveliness()
    subs = [
        lv.declare_subscriber(k, alive.on_sample, history=True)
        for k in (keys.alive_databank_all(), keys.alive_robot("*"))
    ]
    return alive, subs


@dataclass
class Track:
    """One robot's recorded states: the last one and a downsampled (t, q) history."""

    last: RobotState
    t0_ns: int
    times: list[float] = field(default_factory=list)
    qs: list[list[float]] = field(default_factory=list)
    bases: list[list[float]] = field(default_factory=list)
    received: int = 0
    problems: dict[str, str] = field(default_factory=dict)
    """First detail of each troubled status seen (error, databank_unreachable, estop)."""


PROBLEMS = frozenset({"error", "databank_unreachable", "estop"})


class StateRecorder:
    """Keeps each robot's last RobotState and a history for trajectory plots.

    History is kept at most every ``every_s`` seconds of robot time (50 Hz x minutes of
    joint vectors is small, but a plot needs no more). Thread-safe; waits use a Condition.
    """

    def __init__(self, keys: Keys, every_s: float = 0.02, history: bool = True) -> None:
        self.keys = keys
        self.every_ns = int(every_s * 1e9)
        self.history = history
        self.tracks: dict[str, Track] = {}
        self.changed = threading.Condition()
        self.errors = 0
        self._sub: object | None = None

    def start(self, session: zenoh.Session) -> StateRecorder:
        self._sub = session.declare_subscriber(self.keys.state("*"), self.on_sample)
        return self

    def close(self) -> None:
        if self._sub is not None:
            undeclare(self._sub)  # type: ignore[arg-type]
            self._sub = None

    def on_sample(self, sample: zenoh.Sample) -> None:
        try:
            state = decode(sample.payload.to_bytes(), RobotState)
        except KinesphereError:
            self.errors += 1
            return
        with self.changed:
            track = self.tracks.get(state.robot_id)
            if track is None:
                track = self.tracks[state.robot_id] = Track(state, state.stamp_ns)
            if state.seq < track.last.seq and track.received:
                if state.stamp_ns <= track.last.stamp_ns:
                    return  # an old sample arriving late; a restarted agent has a newer stamp
            track.last = state
            track.received += 1
            if state.status in PROBLEMS and state.status not in track.problems:
                track.problems[state.status] = state.detail
            if self.history:
                t = (state.stamp_ns - track.t0_ns) / 1e9
                if not track.times or (t - track.times[-1]) * 1e9 >= self.every_ns:
                    track.times.append(t)
                    track.qs.append(list(state.q))
                    track.bases.append(list(state.base_pose))
            self.changed.notify_all()

    def last(self, robot_id: str) -> RobotState | None:
        with self.changed:
            track = self.tracks.get(robot_id)
            return track.last if track else None

    def problems(self) -> dict[str, dict[str, str]]:
        """Per robot, the troubled statuses it reported during the run, with a detail."""
        with self.changed:
            return {rid: dict(t.problems) for rid, t in self.tracks.items() if t.problems}

    def snapshot(self) -> dict[str, RobotState]:
        with self.changed:
            return {rid: t.last for rid, t in self.tracks.items()}

    def wait_for(self, pred: Callable[[dict[str, RobotState]], bool], timeout: float) -> bool:
        """Wait until ``pred(last states)`` holds; False on timeout."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                if pred({rid: t.last for rid, t in self.tracks.items()}):
                    return True
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.changed.wait(min(left, 0.5))

    def wait_fresh(self, robots: Iterable[str], after_ns: int, timeout: float) -> bool:
        """Wait until every robot in ``robots`` reported a state stamped after ``after_ns``."""
        wanted = list(robots)
        return self.wait_for(
            lambda s: all(r in s and s[r].stamp_ns > after_ns for r in wanted), timeout
        )


SETTLED = frozenset({"idle", "holding", "stopped"})


def is_settled(state: RobotState, tol: float = 1e-3) -> bool:
    """Not moving: a resting status and every joint velocity below ``tol``."""
    return state.status in SETTLED and all(abs(v) < tol for v in state.qd)
