"""The agent's side of motion that does not hit itself (:mod:`kinesphere.platforms.clearance`).

A new target starts at once along the straight joint-space way (so command latency stays at the
floor) while a worker thread checks that way against the robot's collision geometry; its
finding comes a few milliseconds later, long before the limb is anywhere near the touch it
predicts. On a loaded machine it may come later: the joints never run more than
:data:`UNCHECKED_S` of robot time on an unchecked way, they brake and wait for the finding
there (and go on once it is clear). What they would run meanwhile, the plan for that long and
then the brake to rest, is checked on the control thread before the first step (a course of a
few dozen positions Ruckig computes ahead, a few collision checks): when it touches, they do
not set out along it and the route is planned from where they rest, so how late the finding
comes never decides whether they touch. A clear way goes on. A touching one is braked; where the
joints come to rest the planner's waypoints start (planned from there, not from where the move
began: the brake took them some way along), each leg followed from rest with
phase-synchronised Ruckig, so the joints travel the straight lines that were checked, still
jerk-limited. No route at all brakes, and the
fault names the links that would touch. During motion, a contact between two links that the
motion did not start with (a push from outside, a body straying from its plan) halts every
joint and is reported with the pair.

Cheap under a command stream, because it runs on the control thread: the same target again
(a gamepad streams it at 30 Hz, a flood repeats it) restarts nothing, contacts are listed only
when the body says something touches, and the worker checks only the newest target, no more
often than every :data:`CHECK_GAP_S` while targets keep coming (its Python competes with the
control loop for the GIL), and not at all when the new way lies on one already found clear.

The hook is small: :class:`~kinesphere.robots.agent.controller.Controller` calls
:meth:`Guard.move` instead of retargeting directly and :meth:`Guard.before_step` /
:meth:`Guard.after_step` around each step; the fault shows in the agent's state.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from kinesphere.platforms.clearance import Clearance, Touch

if TYPE_CHECKING:
    from kinesphere.robots.agent.body import Body
    from kinesphere.robots.agent.trajectory import Aim, Clamp, JointTrajectory

log = logging.getLogger(__name__)

CHECK_GAP_S = 0.02
"""s: while new targets keep arriving, a check starts at most this long after the previous one
began (the newest target then); the first target after a quiet spell is checked at once."""
CHECKING = threading.Lock()
"""One way check at a time per process: a fleet host's control loop then competes for the
interpreter with one checker, not with one per robot after a command to all (48 at once held
ticks up to 100 ms); waiting checkers block on the lock, not on the interpreter."""
UNCHECKED_S = 0.1
"""s of robot time: how long the joints may move along a straight way still being checked
before they brake for its finding (the check takes milliseconds on an idle machine; how late
it comes under load must not decide how far the limb goes unchecked)."""
COURSE_EVERY_S = 0.02
"""s of robot time between two positions of a move's course ahead (:meth:`Guard.move`): the
path between them is taken as straight (off the curve by ~0.2 mrad at the acceleration limit)
and checked every PATH_STEP along it."""
ON_WAY_TOL = 1e-6
"""rad (m): how far from a way found clear a new start or goal may lie and still be on it."""


@dataclass(frozen=True)
class Blocked:
    """No route reaches the target; ``touch`` is what blocks the straight way."""

    touch: Touch


@dataclass(frozen=True)
class Ask:
    """A way for the worker: check the straight way from ``start`` to ``goal`` (then the
    control thread brakes if it touches), or plan the ``route`` from where the joints rest."""

    generation: int
    start: np.ndarray
    goal: np.ndarray
    route: bool = False


Finding = Touch | list[np.ndarray] | Blocked
"""On one move: the straight way touches (brake now; once at rest, the route from there is
asked), or the route (waypoints ending at the goal; ``[goal]`` for a clear straight way) or
Blocked."""


class Guard:
    """Plans each move of one body's joints on a worker thread and follows the route."""

    def __init__(self, clearance: Clearance, body: Body) -> None:
        self.clearance = clearance
        self._near = Clearance(clearance.pm)
        """The control thread's own checks (:meth:`move`; the worker's MjData is the worker's)."""
        self.body = body
        self.fault = ""
        """Why the joints were halted or refused ("" when they were not)."""
        self.legs: list[np.ndarray] = []
        """Waypoints still to go (the last is the goal); empty on a direct way."""
        self.checks = 0
        """Straight ways checked by the worker (skipped ones not counted)."""
        self.skipped = 0
        """New targets that needed no check: on a way already found clear."""
        self._goal: np.ndarray | None = None
        """The target of the move under way (every joint), until a halt or stop cancels it."""
        self._generation = 0
        self._asked: Ask | None = None
        self._findings: list[tuple[int, Finding]] = []
        self._clear: tuple[np.ndarray, np.ndarray] | None = None
        """The last straight way found clear (worker thread only)."""
        self._start_contacts: frozenset[tuple[str, str]] = frozenset()
        self._braked = self._halted = False
        self._unchecked = 0
        """Steps the joints may still take along the straight way before its finding."""
        self._replan = False
        """Braked on a touching way: a route is asked from where the joints come to rest."""
        self._ask: Ask | None = None
        """A move asked this step, handed to the worker after the step (:meth:`after_step`)."""
        self.notify: Callable[[], None] | None = None
        """Called (on the worker thread) after a finding is posted: a fleet host wakes the
        robot for it (``Agent.needs_cycle``); a lone agent looks every step anyway."""
        self._wake = threading.Condition()
        self._busy = False
        self._closed = False
        self._thread = threading.Thread(target=self._work, name="guard-planner", daemon=True)
        self._thread.start()

    @property
    def pending(self) -> bool:
        """A move's way is still being checked (or its finding not yet applied)."""
        with self._wake:
            return (self._ask is not None or self._asked is not None or self._busy
                    or self._replan
                    or any(g == self._generation for g, _ in self._findings))

    @property
    def idle(self) -> bool:
        """Nothing for the control thread to do before or after a step but watch for
        contacts: no move to hand over, no finding to apply, no leg to start (lock-free: a
        finding posted while this reads is applied at the next step)."""
        return not (self._ask is not None or self._findings or self.legs or self._replan)

    @property
    def unchecked(self) -> bool:
        """The joints run along a way whose finding has not come: :meth:`after_step` counts
        the steps they may still take (a fleet host's glide then ends per robot)."""
        return self._unchecked > 0

    def settle(self, timeout: float) -> bool:
        """Wait until the way to the newest target is checked (and a route planned when it
        touches); False on timeout. For tests and tools that step faster than real time, where
        the worker's few milliseconds are many steps."""
        self._hand_over()  # a move asked without a step since is checked now
        with self._wake:
            return self._wake.wait_for(
                lambda: self._closed or (self._asked is None and not self._busy), timeout)

    # --- control thread ----------------------------------------------------------------------
    def move(self, joints: JointTrajectory, aim: Aim, duration: float | None = None
             ) -> list[Clamp]:
        """Start toward ``aim`` at once (arriving no sooner than ``duration`` s) and have the
        way there checked; the target of the move under way again changes nothing (not even
        a halt it came to, nor its arrival time)."""
        goal = self._goal
        if goal is not None and not joints.fault and goal[aim.index].tolist() == aim.targets:
            return list(aim.clamps)
        start = joints.position.copy()
        base = goal if goal is not None and self.legs else None  # not a waypoint's joints
        clamps = joints.retarget(aim, straight=True, base=base, duration=duration)
        self._goal = joints.target.copy()
        self.legs = []
        self.fault = ""
        self._braked = self._halted = self._replan = False
        self._unchecked = max(1, round(UNCHECKED_S / joints.dt))
        self._start_contacts = (_pairs(self.body.contacts()) if self.body.touching()
                                else frozenset())
        # Only this thread writes the generation; the worker reads it under the lock and a
        # finding on an older one is dropped either way (_post, _take).
        self._generation += 1
        near = self._near
        if near.path(joints.course(self._unchecked * joints.dt, COURSE_EVERY_S),
                     near.contacts(start)) is not None:
            # what the joints would run before a late finding touches: no step along it, the
            # route from where they rest (as if the finding had come before the first step)
            joints.stop()
            self._braked = self._replan = True
            self._unchecked = 0
            return clamps
        self._ask = Ask(self._generation, start, self._goal)  # handed over after the step
        return clamps

    def cancel(self) -> None:
        """Forget the move under way (a halt, a stop): no finding or waypoint applies any more,
        and its target, sent again, starts a new move."""
        self._ask = None
        with self._wake:
            self._generation += 1
            self._asked = None
        self.legs = []
        self._goal = None
        self._unchecked = 0
        self._replan = False

    def before_step(self, joints: JointTrajectory) -> None:
        """Apply a finding that arrived; start the next leg once the last one is at rest."""
        finding = self._take()
        if finding is not None:
            self._unchecked = 0  # checked
        if isinstance(finding, Touch):  # the straight way touches: brake at once, plan at rest
            if not self._braked:
                joints.stop()
                self._braked = True
            self._replan = True
        elif finding is not None:  # the route: clear, or waypoints, or none at all
            if isinstance(finding, Blocked):
                self.fault = (f"blocked: no collision-free way to the target ({finding.touch}); "
                              "braked")
                log.warning("%s", self.fault)
            elif len(finding) > 1 or self._braked:
                self.legs = list(finding)
                log.info("way blocked; going via %d waypoint(s)", len(finding) - 1)
        if self._replan and not joints.moving and self._goal is not None:
            self._replan = False  # the route from here: the brake went some way along
            self._ask = Ask(self._generation, joints.position.copy(), self._goal, route=True)
        if self.legs and not joints.moving:
            joints.go_to(self.legs.pop(0))

    def after_step(self, joints: JointTrajectory) -> None:
        """Wake the worker for a move this step started (not earlier: its checks would take
        the interpreter from the first step toward the new target, the command's latency);
        halt on a contact the motion did not start with, naming the links (once)."""
        if self._ask is not None:
            self._hand_over()
        if self._unchecked > 0 and joints.moving:
            self._unchecked -= 1
            if self._unchecked == 0 and not self._braked:  # the finding is late: wait for it
                joints.stop()
                self._braked = True
                log.info("way still being checked after %g s; braked until it is", UNCHECKED_S)
        if self._halted or not (joints.moving or self.legs) or not self.body.touching():
            return
        new = _pairs(self.body.contacts()) - self._start_contacts
        if new:
            a, b = sorted(new)[0]
            with self._wake:  # no finding on this move applies any more; its target stays
                self._generation += 1
                self._asked = None
            self.legs = []
            joints.stop()
            self._halted = True
            self.fault = f"contact {a}/{b} during motion; halted"
            log.warning("%s", self.fault)

    def _hand_over(self) -> None:
        """Give the worker the move asked this step, if any, and wake it."""
        ask, self._ask = self._ask, None
        if ask is not None:  # of the current generation: a cancel drops the ask with it
            with self._wake:
                self._asked = ask
                self._wake.notify_all()

    def close(self) -> None:
        with self._wake:
            self._closed = True
            self._wake.notify_all()
        self._thread.join(timeout=5.0)

    def _take(self) -> Finding | None:
        """The oldest finding on the current move, if one has arrived."""
        if not self._findings:  # every step asks: the usual answer without the lock
            return None
        with self._wake:
            while self._findings and self._findings[0][0] != self._generation:
                self._findings.pop(0)
            return self._findings.pop(0)[1] if self._findings else None

    # --- worker thread -----------------------------------------------------------------------
    def _work(self) -> None:
        began = -CHECK_GAP_S
        while True:
            with self._wake:
                while self._asked is None and not self._closed:
                    self._wake.wait()
                # a stream of targets: let it settle until the gap has passed, then the newest
                while not self._closed and (rest := began + CHECK_GAP_S - time.monotonic()) > 0:
                    self._wake.wait(rest)
                if self._closed:
                    return
                if self._asked is None:  # cancelled meanwhile
                    continue
                asked, self._asked = self._asked, None
                self._busy = True
            began = time.monotonic()
            try:
                with CHECKING:
                    self._check(asked)
            except Exception:  # a planner bug must not stop the checks for good
                log.exception("planning the way to %s failed", asked.goal)
            finally:
                with self._wake:
                    self._busy = False
                    self._wake.notify_all()

    def _check(self, asked: Ask) -> None:
        """The straight way alone (milliseconds); the route, asked once the joints braked to
        rest on a way that touches, from there."""
        generation, start, goal = asked.generation, asked.start, asked.goal
        if asked.route:
            route = self.clearance.route(start, goal)
            self._post(generation, Blocked(route) if isinstance(route, Touch) else route)
            return
        clear = self._clear
        if clear is not None and _on_way(start, *clear) and _on_way(goal, *clear):
            self.skipped += 1
            self._post(generation, [goal])
            return
        self.checks += 1
        touch = self.clearance.leg(start, goal, self.clearance.contacts(start))
        if touch is None:
            self._clear = (start, goal)
            self._post(generation, [goal])
            return
        self._post(generation, touch)

    def _post(self, generation: int, finding: Finding) -> None:
        with self._wake:
            if generation != self._generation:
                return
            self._findings.append((generation, finding))
        if self.notify is not None:
            self.notify()


def make_guard(body: Body, platform: str) -> Guard:
    """A guard for ``body`` checking against ``platform``'s MuJoCo model (the body's own when
    it is simulated, else compiled once for the checks)."""
    from kinesphere.platforms.mjcf import platform_model

    pm = getattr(body, "pm", None) or platform_model(platform, visuals=False)
    return Guard(Clearance(pm), body)


def _on_way(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> bool:
    """``q`` lies on the straight segment from ``a`` to ``b``."""
    d = b - a
    dd = float(d @ d)
    t = float((q - a) @ d) / dd if dd > 0.0 else 0.0
    t = min(max(t, 0.0), 1.0)
    return float(np.max(np.abs(q - (a + t * d)), initial=0.0)) <= ON_WAY_TOL


def _pairs(contacts: list[tuple[str, str]]) -> frozenset[tuple[str, str]]:
    return frozenset((a, b) if a <= b else (b, a) for a, b in contacts)
