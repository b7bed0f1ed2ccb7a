"""Online jerk-limited trajectories for every joint of P, one Ruckig instance for all of them.

Why one generator for all joints: a pose moves several limbs and Ruckig time-synchronises
the DoFs, so the joints of a pose start and arrive together (a coordinated gesture rather
than each joint racing to its target). Why online: every control step passes Ruckig's own
output back as the next input, so a retarget mid-motion starts from the current position,
velocity and acceleration and the motion stays continuous and jerk-limited.

Targets are clamped inside the joint limits by a margin (the position servos lag and
overshoot a little; the margin keeps the simulated joint off its hard stop), and Ruckig is
also given the hard limits so a retarget that would brake past one is rejected in favour of a
less synchronised, shorter profile. Joints a pose does not name keep their last target.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from ruckig import (
    ControlInterface,
    InputParameter,
    OutputParameter,
    Result,
    Ruckig,
    Synchronization,
)

from kinesphere.eurdf import JointLimit
from kinesphere.robots.agent.base import update

log = logging.getLogger(__name__)

DEFAULT_MARGIN = 0.01
"""Target clamp margin inside each limit, rad (or m); shrunk for joints with a tiny range."""
LIMIT_SLACK = 1e-6
"""A request this close outside a limit is rounding, not a bad target."""
DEFAULT_VELOCITY = 1.0
"""Velocity limit for a joint whose eURDF gives none (rad/s or m/s)."""


@dataclass(frozen=True)
class Clamp:
    """A target moved inside the limits: what was asked and what will be reached.

    ``beyond`` is true when the request lay outside the joint's limits themselves; moving an
    in-limit target off the margin is routine (ECL poses often sit at a limit) and not news.
    """

    joint: str
    requested: float
    target: float
    beyond: bool


def clamp_margin(limit: JointLimit, margin: float = DEFAULT_MARGIN) -> float:
    """The margin used for ``limit``: at most 5 % of the range, so small joints keep a range."""
    span = limit.upper - limit.lower
    return min(margin, 0.05 * span) if math.isfinite(span) else 0.0


class JointTrajectory:
    """Ruckig over the joints ``names``: retarget, stop, and one ``step`` per control cycle.

    After each :meth:`step`, :attr:`position`, :attr:`velocity` and :attr:`acceleration`
    hold the commanded state at the new time (what the position servos track).
    """

    def __init__(
        self,
        limits: Sequence[JointLimit],
        max_acceleration: float,
        max_jerk: float,
        dt: float,
        start: Sequence[float],
        margin: float = DEFAULT_MARGIN,
    ) -> None:
        n = len(limits)
        if len(start) != n:
            raise ValueError(f"start has {len(start)} values for {n} joints")
        self.names = tuple(lim.name for lim in limits)
        self.limits = tuple(limits)
        self.index = {name: i for i, name in enumerate(self.names)}
        self.dt = dt
        self._lo = np.array([lim.lower + clamp_margin(lim, margin) for lim in limits])
        self._hi = np.array([lim.upper - clamp_margin(lim, margin) for lim in limits])
        self.max_velocity = np.array(
            [lim.velocity if math.isfinite(lim.velocity) and lim.velocity > 0 else DEFAULT_VELOCITY
             for lim in limits]
        )
        self.max_acceleration = float(max_acceleration)
        self.max_jerk = float(max_jerk)
        self.position = np.array(start, dtype=float)
        self.velocity = np.zeros(n)
        self.acceleration = np.zeros(n)
        self.target = self.position.copy()
        self.clamped: dict[str, Clamp] = {}
        self.stopping = False
        self.active = False
        self._otg = Ruckig(n, dt) if n else None
        self._inp = InputParameter(n)
        self._out = OutputParameter(n)
        inp = self._inp
        inp.current_position = list(self.position)
        inp.current_velocity = [0.0] * n
        inp.current_acceleration = [0.0] * n
        inp.target_position = list(self.target)
        inp.target_velocity = [0.0] * n
        inp.target_acceleration = [0.0] * n
        inp.max_velocity = list(self.max_velocity)
        inp.max_acceleration = [self.max_acceleration] * n
        inp.max_jerk = [self.max_jerk] * n
        inp.min_position = [lim.lower for lim in limits]
        inp.max_position = [lim.upper for lim in limits]

    @property
    def dof(self) -> int:
        return len(self.names)

    @property
    def moving(self) -> bool:
        """True while a trajectory (or a stop) is still being followed."""
        return self.active

    def clamp(self, joints: Mapping[str, float]) -> tuple[dict[str, float], list[Clamp]]:
        """``joints`` inside the limits with margin, and the joints that had to move."""
        out: dict[str, float] = {}
        clamps: list[Clamp] = []
        for name, value in joints.items():
            i = self.index[name]
            if not math.isfinite(value):
                raise ValueError(f"{name} = {value}")
            target = float(min(max(value, self._lo[i]), self._hi[i]))
            if abs(target - value) > 1e-9:
                lim = self.limits[i]
                beyond = not lim.lower - LIMIT_SLACK <= value <= lim.upper + LIMIT_SLACK
                clamps.append(Clamp(name, float(value), target, beyond))
            out[name] = target
        return out, clamps

    def retarget(self, joints: Mapping[str, float]) -> list[Clamp]:
        """Move the named joints to ``joints`` (clamped); the others keep their last target.

        Unknown joint names (KeyError) and non-finite values (ValueError) change nothing.
        """
        unknown = sorted(set(joints) - set(self.index))
        if unknown:
            raise KeyError(", ".join(unknown))
        targets, clamps = self.clamp(joints)
        for name, value in targets.items():
            self.target[self.index[name]] = value
        for name in targets:
            self.clamped.pop(name, None)
        self.clamped.update({c.joint: c for c in clamps if c.beyond})
        self.stopping = False
        self._inp.control_interface = ControlInterface.Position
        self._inp.synchronization = Synchronization.Time
        self._inp.target_position = list(self.target)
        self.active = True
        return clamps

    def stop(self) -> None:
        """Brake every joint to rest where it is, jerk-limited (the fastest stop the limits allow).

        The targets become wherever the joints come to rest.
        """
        self.stopping = True
        self.active = True
        inp = self._inp
        inp.control_interface = ControlInterface.Velocity
        inp.synchronization = Synchronization.No
        inp.target_velocity = [0.0] * self.dof

    def step(self) -> None:
        """Advance one control cycle along the current trajectory."""
        if self._otg is None or not self.active:
            return
        result = update(self._otg, self._inp, self._out)
        if result is None:
            result = self._recover()
        if result is None:  # never seen: hold where the last output was, rather than crash
            log.error("ruckig cannot brake from %s; holding", list(self.position))
            self._inp.current_position = list(self.position)
            self._inp.current_velocity = [0.0] * self.dof
            self._inp.current_acceleration = [0.0] * self.dof
            self.stopping = True
            self._settle()
            return
        out = self._out
        self.position[:] = out.new_position
        self.velocity[:] = out.new_velocity
        self.acceleration[:] = out.new_acceleration
        out.pass_to_input(self._inp)
        if result == Result.Finished:
            self._settle()

    def _recover(self) -> Result | None:
        """A profile Ruckig refused (limits, synchronisation): try looser ones, then brake."""
        inp, otg = self._inp, self._otg
        assert otg is not None
        if inp.synchronization != Synchronization.No:
            inp.synchronization = Synchronization.No
            result = update(otg, inp, self._out)
            if result is not None:
                return result
        log.warning("ruckig cannot reach targets %s; braking instead", list(self.target))
        inp.control_interface = ControlInterface.Velocity
        inp.target_velocity = [0.0] * self.dof
        self.stopping = True
        return update(otg, inp, self._out)

    def _settle(self) -> None:
        """At rest: hold here in position mode (after a stop, here is the new target)."""
        self.active = False
        if self.stopping:
            self.target[:] = self.position
            self.stopping = False
        inp = self._inp
        inp.control_interface = ControlInterface.Position
        inp.synchronization = Synchronization.Time
        inp.target_position = list(self.target)
        self.velocity[:] = 0.0
        self.acceleration[:] = 0.0
