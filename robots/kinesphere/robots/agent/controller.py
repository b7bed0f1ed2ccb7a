"""Motion without the network: the trajectory generators driving a :class:`Body`.

One control step is: Ruckig update for the joints (and the base), the outputs commanded to the
body (joint positions, base body-frame velocity), and the body's step. It is single-threaded
and knows nothing about wall-clock time, so the runtime can pace it to real time while tests
and benchmarks step it as fast as they like.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np

from kinesphere.robots.agent.base import BaseController, make_base
from kinesphere.robots.agent.body import AT_REST, Body, Reading
from kinesphere.robots.agent.guard import Guard
from kinesphere.robots.agent.ledger import Ledger
from kinesphere.robots.agent.options import DEFAULT_MARGIN
from kinesphere.robots.agent.otg import Otg
from kinesphere.robots.agent.trajectory import Aim, Clamp, JointTrajectory

BLOCKED_TOL = 0.05
"""rad (m): a joint this far from where its finished trajectory ended is blocked."""


class Controller:
    """Joint and base trajectories for one body, stepped every ``body.dt`` seconds; its robot
    time is row ``slot`` of ``ledger`` (a fleet host's, shared by its robots; else its own)."""

    def __init__(self, body: Body, margin: float = DEFAULT_MARGIN, guard: Guard | None = None,
                 ledger: Ledger | None = None, slot: int = 0):
        self.body = body
        self.ledger = Ledger(1, body.dt) if ledger is None else ledger
        self.slot = slot
        self._steps = self.ledger.steps
        self.guard = guard
        """Checks each move against the robot's geometry (``guard.py``); None: unchecked."""
        self.platform = body.platform
        self.dt = body.dt
        self.joint_names = body.joint_names
        self._reading: Reading | None = None
        self._read_at = -1
        """The step count when :attr:`_reading` was read."""
        start = self.reading()
        self.joints = JointTrajectory(
            body.limits,
            self.platform.max_acceleration,
            self.platform.max_jerk,
            self.dt,
            start.q,
            margin,
        )
        self._joints_otg = self.joints.generator
        """The joints' generator (read every step: one attribute, not two properties)."""
        self.base: BaseController | None = make_base(self.platform.base, self.dt)
        if self.base is not None:
            self.base.reset(start.base_pose)
        self.on_step: Callable[[Controller], None] | None = None
        """Called after every step (tests record the Ruckig outputs here)."""

    @property
    def steps(self) -> int:
        """Control steps taken."""
        return int(self._steps[self.slot])

    @property
    def time(self) -> float:
        """Robot time (s): the steps taken times the period."""
        return float(self._steps[self.slot]) * self.dt

    @property
    def moving(self) -> bool:
        """A trajectory, drive or stop is still being followed."""
        return self._joints_otg.active or (self.base is not None and self.base.moving)

    @property
    def deciding(self) -> bool:
        """The guard has still to decide the way of the move under way (its check or route is
        not in, or waypoints are ahead): the joints may rest meanwhile, braked for a late
        finding, yet the motion is not over (``Conduct.after_step``)."""
        guard = self.guard
        return guard is not None and (bool(guard.legs) or guard.pending)

    def move(self, joints: Mapping[str, float] | Aim, duration: float | None = None
             ) -> list[Clamp]:
        """Retarget the named joints (or a compiled :class:`Aim`), arriving no sooner than
        ``duration`` seconds from now when given: through the guard (checked, via waypoints
        when the straight way touches something) when there is one."""
        aim = joints if isinstance(joints, Aim) else self.joints.aim(joints)
        if self.guard is None:
            return self.joints.retarget(aim, duration=duration)
        return self.guard.move(self.joints, aim, duration)

    @property
    def remaining(self) -> float:
        """Seconds until the joints and the base arrive, as planned (0 at rest); a route
        around a contact adds its waypoints still to go, at the least time each can take."""
        base = self.base.remaining if self.base is not None else 0.0
        joints, at = self.joints.remaining, self.joints.target
        for leg in self.guard.legs if self.guard is not None else []:
            joints += self.joints.least_time(at, leg)
            at = leg
        return max(joints, base)

    def step(self) -> None:
        """One control cycle: trajectories forward, body commanded, body stepped."""
        self.prepare()
        self.body.step()
        self.finish()

    def prepare(self) -> None:
        """The cycle up to the body's step: trajectories forward, body commanded. (A fleet
        host steps many bodies between :meth:`prepare` and :meth:`finish`, and takes the
        steps of followed joint trajectories for all of them at once between :meth:`guide`
        and :meth:`command`: ``follow.py``.)"""
        self.guide()
        self.command()

    def guide(self) -> None:
        """The guard's verdicts and next leg, before the trajectories step."""
        if self.guard is not None:
            self.guard.before_step(self.joints)

    def command(self) -> None:
        """Trajectories forward (a followed joint trajectory has been already: ``follow.py``),
        their setpoints to the body."""
        self._joints_otg.step()
        base = self.base
        if base is not None and base.stepping:
            base.step()
            self.body.command(self._joints_otg.position, base.body_twist)
        else:  # a base at rest stays where its servos hold it
            self.body.command(self._joints_otg.position, AT_REST)

    def finish(self) -> None:
        """The cycle after the body's step: one period of robot time has passed."""
        if self.guard is not None:
            self.guard.after_step(self.joints)
        self.elapse()

    def elapse(self) -> None:
        """One period of robot time has passed (the end of :meth:`finish`: all a fleet host
        does for a robot whose guard has nothing to do, ``Agent.needs_cycle``)."""
        self._steps[self.slot] += 1
        if self.on_step is not None:
            self.on_step(self)

    @property
    def followed(self) -> bool:
        """Whether a fleet host's followers take the steps of every motion under way
        (``follow.py``): nothing is planned or stepped here, nothing can fail here."""
        joints = self._joints_otg
        return ((joints.following or not joints.active)
                and (self.base is None or self.base.followed))

    @property
    def glides(self) -> bool:
        """Whether the next step, unless something arrives, is the followers' step and
        nothing else: they take the joints' step (or the joints rest) and the base either
        rests or its step too (:meth:`command` would only hand the joints' followed output to
        the body, and the base's step integrate what the followers did). A fleet host does
        that itself for all such robots (``fleet.py``); it stays so while the followers take
        the steps."""
        joints, base = self._joints_otg, self.base
        if base is None or not base.stepping:
            return joints.following
        return base.generator.following and (
            joints.following or not (joints.active or joints.came_to_rest))

    @property
    def generators(self) -> list[Otg]:
        """The Ruckig generators of the joints and the base (a fleet host's followers take
        their steps between plans)."""
        gens = [self.joints.generator]
        if self.base is not None:
            gens.append(self.base.generator)
        return gens

    @property
    def unattended(self) -> bool:
        """Whether the next step needs nothing of the controller before the body's step but
        the trajectories forward and the setpoints to the body: the guard has no verdict to
        apply nor leg to start, and no hook watches the steps (``Agent.needs_cycle``)."""
        return (self.guard is None or self.guard.idle) and self.on_step is None

    def halt(self) -> None:
        """Brake joints and base to rest where they are (jerk-limited)."""
        if self.guard is not None:
            self.guard.cancel()
        self.joints.stop()
        if self.base is not None:
            self.base.stop()

    def fail_safe(self) -> None:
        """The last resort when a step failed: the body holds where it is and the
        trajectories start again from there, at rest."""
        if self.guard is not None:
            self.guard.cancel()
        self.body.halt()
        self._reading = None
        now = self.reading()
        self.joints.reset(now.q)
        if self.base is not None:
            self.base.reset(now.base_pose)

    def fault(self) -> str:
        """Why a trajectory was braked instead of followed ("" when none was)."""
        joints = self.joints.fault
        base = self.base.fault if self.base is not None else ""
        guard = self.guard.fault if self.guard is not None else ""
        if not (joints or base or guard):  # every step asks: the usual answer without a join
            return ""
        return "; ".join(f for f in (joints, base, guard) if f)

    def reading(self) -> Reading:
        """The body's measurement after the last step (read once, when first asked for)."""
        steps = int(self._steps[self.slot])
        if self._reading is None or self._read_at != steps:
            self._reading, self._read_at = self.body.read(), steps
        return self._reading

    def q(self) -> list[float]:
        """Measured joint positions in P order."""
        return self.reading().q.tolist()  # type: ignore[no-any-return]

    def qd(self) -> list[float]:
        return self.reading().qd.tolist()  # type: ignore[no-any-return]

    def base_pose(self) -> list[float]:
        """Measured ``[x, y, yaw]`` of the base, yaw in (-pi, pi] (zeros for a fixed base)."""
        return list(self.reading().base_pose)

    def commanded_base_yaw(self) -> float | None:
        return None if self.base is None else float(self.base.pose[2])

    def settle(self, max_steps: int = 100_000, extra: int = 0) -> int:
        """Step until nothing moves (then ``extra`` more steps); returns steps taken."""
        n = 0
        while self.moving and n < max_steps:
            self.step()
            n += 1
        for _ in range(extra):
            self.step()
        return n + extra

    def blocked(self, tol: float = BLOCKED_TOL) -> str:
        """Why the body is not where the trajectory ended, or "" when it is.

        The ECL checks its poses, not the joint-space path to them: an arm can catch on the
        other one on the way and stay there. Saying "at target" then would be a lie.
        """
        error = np.abs(self.reading().q - self.joints.target)
        if not error.size:
            return ""
        at = error.argmax()  # an idle robot asks at every state it publishes: methods, no int()
        if not error[at] > tol:
            return ""
        worst = int(at)
        contacts = sorted({f"{a}/{b}" for a, b in self.body.contacts()})
        touching = f"; self-contact {', '.join(contacts[:3])}" if contacts else ""
        return (f"blocked: {self.joint_names[worst]} is {error[worst]:.3f} from its target"
                f"{touching}")

