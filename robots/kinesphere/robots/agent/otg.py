"""One online Ruckig generator, stepped once per control cycle; the joints and the base share it.

The idiom is Ruckig's own: ``update`` then ``pass_to_input`` every cycle, so a new target
mid-motion starts from the current position, velocity and acceleration and the motion stays
continuous and jerk-limited; a stop is the velocity interface towards zero without
synchronisation (Ruckig's ``examples/06_stop.py``).

Why one wrapper: both users need the same promise. A profile Ruckig refuses is retried looser
(no synchronisation, the full limits instead of scaled ones); if that fails too, the motion
brakes to rest; if even the brake fails, it holds where the last output was. Nothing here
raises into the control loop (the binding raises ``RuckigError`` or ``ValueError`` for some
failures, e.g. a 10 km translation whose duration exceeds Ruckig's maximum): a failure is a
braked hold and a reason in :attr:`Otg.fault`, which the agent reports as ``error``.

On a fleet host the steps between two plans are not taken here: the generator is attached to
the host's :class:`~kinesphere.robots.agent.follow.Followers`, which follow every robot's
trajectory at once on arrays, bit for bit as ``update`` would (``follow.py``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    OutputParameter,
    Result,
    Ruckig,
    Synchronization,
    Trajectory,
)

if TYPE_CHECKING:
    from kinesphere.robots.agent.follow import Followers

log = logging.getLogger(__name__)

Values = Sequence[float] | np.ndarray
"""Per-DoF values: a sequence or a numpy vector."""

FLOOR = 0.3
"""Smallest per-axis share of a limit (:meth:`Otg.scale`). Ruckig needs positive limits on every
DoF, and an axis the motion does not use may still carry velocity from the previous one, which
it must brake in reasonable time; for axis-aligned motions this loosens a vector bound by at
most 4 %."""
_WORKING = (Result.Working, Result.Finished)
_CODES = {
    -100: "invalid input", -101: "the trajectory would last longer than Ruckig allows",
    -102: "a position limit is in the way", -104: "a limit is zero",
    -110: "no execution time found", -111: "no synchronisation found",
}
"""Ruckig's error results by code (the binding knows only some of them)."""


def _reason(failure: object) -> str:
    """A short reason for a failed ``update``: its result, or the exception it raised."""
    code = getattr(failure, "value", None)
    if isinstance(failure, ValueError):  # "-101 is not a valid Result"
        head = str(failure).split()[0] if str(failure).split() else ""
        code = int(head) if head.lstrip("-").isdigit() else None
    if isinstance(code, int) and code in _CODES:
        return _CODES[code]
    text = str(failure).strip().splitlines()
    if not text:
        return repr(failure)
    return text[0].removeprefix("[ruckig]").strip().removesuffix("input:").strip(" ,:")


def _calculated(ruckig: Ruckig, inp: InputParameter, trajectory: Trajectory) -> bool:
    """Whether Ruckig calculated ``trajectory`` for ``inp`` (offline; it may raise, as
    ``update`` may)."""
    try:
        return ruckig.calculate(inp, trajectory) in _WORKING
    except Exception:  # RuckigError, or ValueError for codes the binding lacks
        return False


class Otg:
    """Ruckig over ``n`` DoFs with its input and output; :meth:`step` advances one cycle.

    After each step :attr:`position`, :attr:`velocity` and :attr:`acceleration` hold the
    commanded state at the new time. :attr:`target` is the position the DoFs are held at once
    at rest (after a brake: wherever they stopped).
    """

    def __init__(
        self, n: int, dt: float, vmax: Values, amax: Values,
        jmax: Values, start: Values | None = None,
        lower: Values | None = None, upper: Values | None = None,
    ) -> None:
        self.n = n
        self.dt = dt
        self.vmax, self.amax, self.jmax = list(vmax), list(amax), list(jmax)
        self.position = np.zeros(n) if start is None else np.array(start, dtype=float)
        self.velocity = np.zeros(n)
        self.acceleration = np.zeros(n)
        self.target = self.position.copy()
        self.active = False
        self.braking = False
        self.fault = ""
        """Why the last motion was braked instead of followed; "" when it was not."""
        self._remaining = 0.0
        """What :attr:`remaining` says while the steps are taken here."""
        self._why = ""
        self.following = False
        """Whether :class:`Followers` take the steps of the trajectory now (not :meth:`step`)."""
        self.came_to_rest = False
        """The followers' last step brought the motion to rest, and :meth:`step` has not said
        so yet (its owner still has that step to account for)."""
        self.followable = True
        """Whether :class:`Followers` may take the steps once Ruckig planned (False: the
        owner plans again before every step, as a base turning while it drives does)."""
        self._followers: Followers | None = None
        self._slot = -1
        self._otg = Ruckig(n, dt)
        self._inp = InputParameter(n)
        self._out = OutputParameter(n)
        inp = self._inp
        inp.current_position = list(self.position)
        inp.current_velocity = [0.0] * n
        inp.current_acceleration = [0.0] * n
        inp.target_position = list(self.target)
        inp.target_velocity = [0.0] * n
        inp.target_acceleration = [0.0] * n
        if lower is not None and upper is not None:
            inp.min_position = list(lower)
            inp.max_position = list(upper)
        self.scale([1.0] * n)

    def attach(self, followers: Followers, slot: int, rows: slice) -> None:
        """Let ``followers`` take the steps along each trajectory once Ruckig planned it; the
        outputs become views of their arrays (``rows``). From then on their ``advance`` must
        come before every :meth:`step` (a fleet host's tick does both)."""
        for name in ("position", "velocity", "acceleration"):
            shared = getattr(followers, name)[rows]
            shared[:] = getattr(self, name)
            setattr(self, name, shared)
        self._followers, self._slot = followers, slot

    @property
    def remaining(self) -> float:
        """Seconds the motion planned last still takes from the latest output (Ruckig's
        trajectory duration, counted from the step that planned it; the followers' clock
        while they take the steps)."""
        if self.following:
            assert self._followers is not None
            return self._followers.left(self._slot)
        return self._remaining

    def arrived(self) -> None:
        """The followed trajectory ended (``Finished``): rest, unless it cruises on."""
        if self.cruising:
            return  # a cruise that reached its velocity extrapolates at it
        self._detach()
        self.came_to_rest = self._rest()

    def _detach(self) -> None:
        """Take the steps here again: Ruckig's input continues from the followed state (what
        ``pass_to_input`` would have left there)."""
        if not self.following:
            return
        self.following = False
        assert self._followers is not None
        self._remaining = self._followers.left(self._slot)
        self._followers.drop(self._slot)
        inp = self._inp
        inp.current_position = self.position.tolist()
        inp.current_velocity = self.velocity.tolist()
        inp.current_acceleration = self.acceleration.tolist()

    def reset(self, position: Values) -> None:
        """At rest at ``position`` (where the body was found)."""
        self._detach()
        self.came_to_rest = False
        self.position[:] = position
        self._inp.current_position = list(self.position)
        self._inp.current_velocity = [0.0] * self.n
        self._inp.current_acceleration = [0.0] * self.n
        self.braking = True  # so that resting takes ``position`` as the target
        self._rest()

    def scale(self, share: Values) -> None:
        """Limits per axis = limit x share (a direction's components, at least :data:`FLOOR`)."""
        s = [max(abs(x), FLOOR) for x in share]
        limits = ([v * k for v, k in zip(self.vmax, s, strict=True)],
                  [a * k for a, k in zip(self.amax, s, strict=True)],
                  [j * k for j, k in zip(self.jmax, s, strict=True)])
        inp = self._inp
        if limits == (inp.max_velocity, inp.max_acceleration, inp.max_jerk):
            return  # Ruckig's input is unchanged: it would follow on
        self._detach()
        inp.max_velocity, inp.max_acceleration, inp.max_jerk = limits

    def go_to(self, target: Values, sync: Synchronization = Synchronization.Time,
              duration: float | None = None) -> None:
        """Reach ``target`` at rest, taking at least ``duration`` seconds when given (Ruckig's
        minimum duration: a motion that could be quicker arrives then, one that cannot
        arrives as soon as the limits allow)."""
        self.target[:] = target
        self._plan(ControlInterface.Position, sync, self.target.tolist(), None,
                   duration if duration is not None and duration > 0 else None)

    def go_at(self, velocity: Values,
              sync: Synchronization = Synchronization.Phase) -> None:
        """Reach ``velocity`` and cruise at it until told otherwise."""
        self._plan(ControlInterface.Velocity, sync, None, [float(v) for v in velocity])

    def brake(self) -> None:
        """Come to rest where the brake ends, the fastest jerk-limited stop the limits allow."""
        self.go_at([0.0] * self.n, Synchronization.No)
        self.braking = True

    def _plan(self, interface: ControlInterface, sync: Synchronization,
              position: list[float] | None, velocity: list[float] | None,
              duration: float | None = None) -> None:
        """A new input for Ruckig (``position`` or ``velocity``: the target that changes;
        ``duration``: the minimum duration, None for none). The same input again changes
        nothing for Ruckig, which follows on (so do followers)."""
        self.came_to_rest = False
        inp = self._inp
        if not (self.following and inp.control_interface == interface
                and inp.synchronization == sync and inp.minimum_duration == duration
                and (position is None or inp.target_position == position)
                and (velocity is None or inp.target_velocity == velocity)):
            self._detach()
            inp.control_interface = interface
            inp.synchronization = sync
            inp.minimum_duration = duration
            if position is not None:
                inp.target_position = position
            if velocity is not None:
                inp.target_velocity = velocity
        self.active = self.n > 0  # Ruckig cannot step zero DoFs
        self.braking = False
        self.fault = ""

    def course(self, brake_after: float, every: float) -> np.ndarray:
        """Where the motion just planned takes the DoFs if it brakes ``brake_after`` s from
        now: positions every ``every`` s along the plan up to then, then along the brake to
        rest, the last where it ends (what the online steps will command, bit for bit at those
        times: the same Ruckig input, calculated ahead). A plan Ruckig refuses is braked now,
        as :meth:`step` would. Why: the guard checks this stretch before the first step of a
        move whose way is still being checked (``guard.py``)."""
        now = (self.position.tolist(), self.velocity.tolist(), self.acceleration.tolist())
        ruckig, plan = Ruckig(self.n), Trajectory(self.n)
        ahead = self._input(*now)
        planned = False
        if self.active and not self.braking:
            planned = _calculated(ruckig, ahead, plan)
            if not planned:  # as _recover: without synchronisation
                ahead.synchronization = Synchronization.No
                planned = _calculated(ruckig, ahead, plan)
        if planned:
            until = min(brake_after, plan.duration)
            times = [*np.arange(0.0, until, every).tolist(), until]
            points = [plan.at_time(t)[0] for t in times]
            if until >= plan.duration:  # arrives before it would brake
                return np.array(points)
            now = plan.at_time(until)
        else:
            points = [now[0]]
        brake = self._input(*now)
        brake.control_interface = ControlInterface.Velocity
        brake.synchronization = Synchronization.No
        brake.minimum_duration = None
        brake.target_velocity = [0.0] * self.n
        if not _calculated(ruckig, brake, plan):
            return np.array(points)
        points += [plan.at_time(t)[0] for t in [*np.arange(every, plan.duration, every).tolist(),
                                                 plan.duration]]
        return np.array(points)

    def _input(self, position: list[float], velocity: list[float],
               acceleration: list[float]) -> InputParameter:
        """A copy of the generator's input (its target, interface, limits) from the state
        given (the binding copies none)."""
        inp, out = self._inp, InputParameter(self.n)
        for name in ("control_interface", "synchronization", "minimum_duration",
                     "target_position", "target_velocity", "target_acceleration",
                     "max_velocity", "max_acceleration", "max_jerk", "min_position",
                     "max_position"):
            setattr(out, name, getattr(inp, name))
        out.current_position, out.current_velocity = position, velocity
        out.current_acceleration = acceleration
        return out

    @property
    def cruising(self) -> bool:
        """Following a non-zero target velocity (a drive)."""
        return (self.active and self._inp.control_interface == ControlInterface.Velocity
                and any(self._inp.target_velocity))

    def step(self) -> bool:
        """Advance one cycle; True when the motion just came to rest (reached or braked)."""
        if not self.active or self.following:
            arrived, self.came_to_rest = self.came_to_rest, False
            return arrived  # the followers took this step
        result = self._update()
        if result is None:
            result = self._recover()
        if result is None:
            return self._hold()
        out = self._out
        if out.new_calculation:
            self._remaining = max(0.0, out.trajectory.duration - out.time)
        else:
            self._remaining = max(0.0, self._remaining - self.dt)
        self.position[:] = out.new_position
        self.velocity[:] = out.new_velocity
        self.acceleration[:] = out.new_acceleration
        out.pass_to_input(self._inp)
        if result != Result.Finished:
            if self._followers is not None and self.followable:
                self._followers.load(self._slot, out.trajectory, out.time)
                self.following = True
            return False
        if self.cruising:
            return False  # a cruise that reached its velocity extrapolates at it
        return self._rest()

    def _update(self) -> Result | None:
        """``update``, or None on failure with the reason kept for :meth:`_recover`."""
        try:
            result = self._otg.update(self._inp, self._out)
        except Exception as exc:  # RuckigError, or ValueError for codes the binding lacks
            self._why = _reason(exc)
            return None
        if result in _WORKING:
            return result
        self._why = _reason(result)
        return None

    def _recover(self) -> Result | None:
        """A profile Ruckig refused: loosen it (full limits, no synchronisation), else brake."""
        inp = self._inp
        self.scale([1.0] * self.n)
        inp.minimum_duration = None
        if inp.synchronization != Synchronization.No:
            inp.synchronization = Synchronization.No
            result = self._update()
            if result is not None:
                return result
        if self.braking:
            return None
        wanted = (f"target {[round(x, 4) for x in inp.target_position]}"
                  if inp.control_interface == ControlInterface.Position
                  else f"velocity {[round(x, 4) for x in inp.target_velocity]}")
        self.fault = f"ruckig cannot plan to {wanted} ({self._why}); braked"
        log.warning("%s", self.fault)
        fault = self.fault
        self.brake()
        self.fault = fault
        return self._update()

    def _hold(self) -> bool:
        """Even the brake failed (never seen): hold where the last output was."""
        self.fault = self.fault or f"ruckig cannot brake ({self._why}); holding"
        log.error("%s at %s", self.fault, list(self.position))
        self._inp.current_position = list(self.position)
        self._inp.current_velocity = [0.0] * self.n
        self._inp.current_acceleration = [0.0] * self.n
        return self._rest()

    def _rest(self) -> bool:
        """At rest: hold here in position mode (after a brake, here is the new target)."""
        if self.braking or self._inp.control_interface == ControlInterface.Velocity:
            self.target[:] = self.position
        self.active = False
        self.braking = False
        self._remaining = 0.0
        inp = self._inp
        inp.control_interface = ControlInterface.Position
        inp.synchronization = Synchronization.Time
        inp.target_position = list(self.target)
        inp.target_velocity = [0.0] * self.n
        # at rest, exactly: the last output leaves ~1e-16 rad/s, enough for Ruckig to find
        # no phase synchronisation for the next move and fall back to time synchronisation,
        # off the straight way the guard checked
        inp.current_velocity = [0.0] * self.n
        inp.current_acceleration = [0.0] * self.n
        self.velocity[:] = 0.0
        self.acceleration[:] = 0.0
        return True
