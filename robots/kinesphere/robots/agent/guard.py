"""The agent's side of motion that does not hit itself (:mod:`kinesphere.robots.clearance`).

A new target starts at once along the straight joint-space way (so command latency stays at the
floor) while a worker thread checks that way against the robot's collision geometry; its
verdict comes a few milliseconds later, long before the limb is anywhere near the touch it
predicts. A clear way goes on. A touching one is braked and replaced by the planner's
waypoints, each leg followed from rest with phase-synchronised Ruckig, so the joints travel
the straight lines that were checked, still jerk-limited. No route at all brakes, and the
fault names the links that would touch. During motion, a contact between two links that the
motion did not start with (a push from outside, a body straying from its plan) halts every
joint and is reported with the pair.

The hook is small: :class:`~kinesphere.robots.agent.controller.Controller` calls
:meth:`Guard.move` instead of retargeting directly and :meth:`Guard.before_step` /
:meth:`Guard.after_step` around each step; the fault shows in the agent's state.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from kinesphere.robots.clearance import Clearance, Touch

if TYPE_CHECKING:
    from kinesphere.robots.agent.body import Body
    from kinesphere.robots.agent.trajectory import Clamp, JointTrajectory

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class Blocked:
    """No route reaches the target; ``touch`` is what blocks the straight way."""

    touch: Touch


Verdict = Touch | list[np.ndarray] | Blocked
"""On one move: the straight way touches (brake now), then the route (waypoints ending at the
goal; ``[goal]`` for a clear straight way) or Blocked."""


class Guard:
    """Plans each move of one body's joints on a worker thread and follows the route."""

    def __init__(self, clearance: Clearance, body: Body) -> None:
        self.clearance = clearance
        self.body = body
        self.fault = ""
        """Why the joints were halted or refused ("" when they were not)."""
        self.legs: list[np.ndarray] = []
        """Waypoints still to go (the last is the goal); empty on a direct way."""
        self._generation = 0
        self._asked: tuple[int, np.ndarray, np.ndarray] | None = None
        self._verdicts: list[tuple[int, Verdict]] = []
        self._start_contacts: frozenset[tuple[str, str]] = frozenset()
        self._braked = self._halted = False
        self._wake = threading.Condition()
        self._busy = False
        self._closed = False
        self._thread = threading.Thread(target=self._work, name="guard-planner", daemon=True)
        self._thread.start()

    @property
    def pending(self) -> bool:
        """A move's way is still being checked (or its verdict not yet applied)."""
        with self._wake:
            return (self._asked is not None or self._busy
                    or any(g == self._generation for g, _ in self._verdicts))

    # --- control thread ----------------------------------------------------------------------
    def move(self, joints: JointTrajectory, targets: Mapping[str, float]) -> list[Clamp]:
        """Start toward ``targets`` at once and have the way there checked."""
        start = joints.position.copy()
        clamps = joints.retarget(targets, straight=True)
        self.legs = []
        self.fault = ""
        self._braked = self._halted = False
        self._start_contacts = _pairs(self.body.contacts())
        with self._wake:
            self._generation += 1
            self._asked = (self._generation, start, joints.target.copy())
            self._wake.notify()
        return clamps

    def cancel(self) -> None:
        """Forget the move under way (a halt, a stop): no verdict or waypoint applies any more."""
        with self._wake:
            self._generation += 1
            self._asked = None
        self.legs = []

    def before_step(self, joints: JointTrajectory) -> None:
        """Apply a verdict that arrived; start the next leg once the last one is at rest."""
        verdict = self._take()
        if isinstance(verdict, Touch):  # the straight way touches: brake at once
            if not self._braked:
                joints.stop()
                self._braked = True
        elif verdict is not None:  # the route: clear, or waypoints, or none at all
            if isinstance(verdict, Blocked):
                self.fault = (f"blocked: no collision-free way to the target ({verdict.touch}); "
                              "braked")
                log.warning("%s", self.fault)
            elif len(verdict) > 1 or self._braked:
                self.legs = list(verdict)
                log.info("way blocked; going via %d waypoint(s)", len(verdict) - 1)
        if self.legs and not joints.moving:
            leg = self.legs.pop(0)
            joints.retarget(dict(zip(joints.names, leg.tolist(), strict=True)), straight=True)

    def after_step(self, joints: JointTrajectory) -> None:
        """Halt on a contact the motion did not start with, naming the links (once)."""
        if self._halted or not (joints.moving or self.legs) or not self.body.touching():
            return
        new = _pairs(self.body.contacts()) - self._start_contacts
        if new:
            a, b = sorted(new)[0]
            self.cancel()
            joints.stop()
            self._halted = True
            self.fault = f"contact {a}/{b} during motion; halted"
            log.warning("%s", self.fault)

    def close(self) -> None:
        with self._wake:
            self._closed = True
            self._wake.notify()
        self._thread.join(timeout=5.0)

    def _take(self) -> Verdict | None:
        """The oldest verdict on the current move, if one has arrived."""
        if not self._verdicts:  # every step asks: the usual answer without the lock
            return None
        with self._wake:
            while self._verdicts and self._verdicts[0][0] != self._generation:
                self._verdicts.pop(0)
            return self._verdicts.pop(0)[1] if self._verdicts else None

    # --- worker thread -----------------------------------------------------------------------
    def _work(self) -> None:
        while True:
            with self._wake:
                while self._asked is None and not self._closed:
                    self._wake.wait()
                if self._closed:
                    return
                asked, self._asked = self._asked, None
                self._busy = True
            assert asked is not None
            generation, start, goal = asked
            try:  # first the straight way alone (milliseconds), then a route if it touches
                touch = self.clearance.leg(start, goal, self.clearance.contacts(start))
                self._post(generation, touch if touch is not None else [goal])
                if touch is not None:
                    route = self.clearance.route(start, goal)
                    self._post(generation, Blocked(route) if isinstance(route, Touch) else route)
            except Exception:  # a planner bug must not stop the checks for good
                log.exception("planning the way to %s failed", goal)
            finally:
                with self._wake:
                    self._busy = False

    def _post(self, generation: int, verdict: Verdict) -> None:
        with self._wake:
            if generation == self._generation:
                self._verdicts.append((generation, verdict))


def make_guard(body: Body, platform: str) -> Guard:
    """A guard for ``body`` checking against ``platform``'s MuJoCo model (the body's own when
    it is simulated, else compiled once for the checks)."""
    from kinesphere.robots.mjcf import platform_model

    pm = getattr(body, "pm", None) or platform_model(platform)
    return Guard(Clearance(pm), body)


def _pairs(contacts: list[tuple[str, str]]) -> frozenset[tuple[str, str]]:
    return frozenset((a, b) if a <= b else (b, a) for a, b in contacts)
