"""Online jerk-limited trajectories for every joint of P, one Ruckig instance for all of them.

Why one generator for all joints: a pose moves several limbs and Ruckig time-synchronises
the DoFs, so the joints of a pose start and arrive together (a coordinated gesture rather
than each joint racing to its target). Why online: every control step passes Ruckig's own
output back as the next input, so a retarget mid-motion starts from the current position,
velocity and acceleration and the motion stays continuous and jerk-limited.

Targets are clamped inside the joint limits by a margin (the position servos lag and
overshoot a little; the margin keeps the simulated joint off its hard stop), and Ruckig is
also given the hard limits so a retarget that would brake past one is rejected in favour of a
less synchronised, shorter profile (``otg.py`` has the fallbacks). Joints a pose does not name
keep their last target.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, NoReturn, TypeVar

import numpy as np
from ruckig import Synchronization

from kinesphere.robots.agent.options import DEFAULT_MARGIN
from kinesphere.robots.agent.otg import Otg, Values

if TYPE_CHECKING:
    from kinesphere.eurdf import JointLimit

LIMIT_SLACK = 1e-6
"""A request this close outside a limit is rounding, not a bad target."""
DEFAULT_VELOCITY = 1.0
"""Velocity limit for a joint whose eURDF gives none (rad/s or m/s)."""

T = TypeVar("T")


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


@dataclass(frozen=True)
class Aim:
    """A pose's targets compiled for one robot's joints: P indices and clamped values as
    vectors, and what the clamp moved. Why: a command for a cached pose is aimed at with a
    vector assignment, not a per-joint Python loop, on its way to the first setpoint (the
    agent keeps one per cached pose, ``conduct.py``)."""

    index: np.ndarray
    values: np.ndarray
    targets: list[float]
    """``values`` as Python floats (compared without numpy's per-call overhead)."""
    names: tuple[str, ...]
    clamps: tuple[Clamp, ...]
    beyond: dict[str, Clamp]
    """The clamps of requests outside the limits themselves, by joint (reported)."""


def clamp_margin(limit: JointLimit, margin: float = DEFAULT_MARGIN) -> float:
    """The margin used for ``limit``: at most 5 % of the range, so small joints keep a range."""
    span = limit.upper - limit.lower
    return min(margin, 0.05 * span) if math.isfinite(span) else 0.0


class _Generated(Generic[T]):
    """The Ruckig generator's attribute of the same name, read through the trajectory: its
    commanded state is the generator's, delegated here once rather than by a property each."""

    def __set_name__(self, owner: type, name: str) -> None:
        self._name = name

    def __get__(self, trajectory: JointTrajectory, owner: type | None = None) -> T:
        value: T = getattr(trajectory.generator, self._name)
        return value

    def __set__(self, trajectory: JointTrajectory, value: NoReturn) -> NoReturn:
        raise AttributeError(f"{self._name} is read-only: the generator's state")


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
        start: Values,
        margin: float = DEFAULT_MARGIN,
    ) -> None:
        n = len(limits)
        if len(start) != n:
            raise ValueError(f"start has {len(start)} values for {n} joints")
        self.names = tuple(lim.name for lim in limits)
        self.limits = tuple(limits)
        self.index = {name: i for i, name in enumerate(self.names)}
        self.dt = dt
        self._lo = [lim.lower + clamp_margin(lim, margin) for lim in limits]
        self._hi = [lim.upper - clamp_margin(lim, margin) for lim in limits]
        """Clamp bounds as Python floats: :meth:`clamp` runs before a command's first step."""
        self.max_velocity = np.array(
            [lim.velocity if math.isfinite(lim.velocity) and lim.velocity > 0 else DEFAULT_VELOCITY
             for lim in limits]
        )
        self.max_acceleration = float(max_acceleration)
        self.max_jerk = float(max_jerk)
        self.clamped: dict[str, Clamp] = {}
        self.generator = Otg(n, dt, self.max_velocity, [self.max_acceleration] * n,
                             [self.max_jerk] * n, start, [lim.lower for lim in limits],
                             [lim.upper for lim in limits])
        """The Ruckig generator of all joints (a fleet host lets its ``Followers`` take the
        steps between plans: ``follow.py``)."""

    @property
    def dof(self) -> int:
        return len(self.names)

    @property
    def moving(self) -> bool:
        """True while a trajectory (or a stop) is still being followed."""
        return self.generator.active

    position = _Generated[np.ndarray]()
    velocity = _Generated[np.ndarray]()
    acceleration = _Generated[np.ndarray]()
    target = _Generated[np.ndarray]()
    """Where the joints are going, or are held (after a stop: where they came to rest)."""
    fault = _Generated[str]()
    """Why the last motion was braked instead of followed ("" when it was not)."""

    @property
    def remaining(self) -> float:
        """Seconds until the motion under way arrives, as planned (0 at rest)."""
        return self.generator.remaining if self.generator.active else 0.0

    def least_time(self, a: np.ndarray, b: np.ndarray) -> float:
        """Seconds a move from ``a`` to ``b`` (every joint) takes at least: the slowest joint
        at its full velocity all the way (a bound from below, for waypoints not yet planned)."""
        if not self.dof:
            return 0.0
        return float(np.max(np.abs(np.asarray(b) - np.asarray(a)) / self.max_velocity))

    def clamp(self, joints: Mapping[str, float]) -> tuple[dict[str, float], list[Clamp]]:
        """``joints`` inside the limits with margin, and the joints that had to move."""
        out: dict[str, float] = {}
        clamps: list[Clamp] = []
        index, lows, highs = self.index, self._lo, self._hi
        for name, value in joints.items():
            i = index[name]
            if not math.isfinite(value):
                raise ValueError(f"{name} = {value}")
            lo, hi = lows[i], highs[i]
            target = lo if value < lo else hi if value > hi else float(value)
            if abs(target - value) > 1e-9:
                lim = self.limits[i]
                beyond = not lim.lower - LIMIT_SLACK <= value <= lim.upper + LIMIT_SLACK
                clamps.append(Clamp(name, float(value), target, beyond))
            out[name] = target
        return out, clamps

    def aim(self, joints: Mapping[str, float]) -> Aim:
        """``joints`` checked, clamped and compiled to vectors (:class:`Aim`). Unknown joint
        names raise KeyError, non-finite values ValueError."""
        if not joints.keys() <= self.index.keys():
            raise KeyError(", ".join(sorted(set(joints) - set(self.index))))
        targets, clamps = self.clamp(joints)
        index = self.index
        values = list(targets.values())
        return Aim(
            np.fromiter((index[name] for name in targets), dtype=np.intp, count=len(targets)),
            np.array(values, dtype=float), values, tuple(targets), tuple(clamps),
            {c.joint: c for c in clamps if c.beyond})

    def retarget(self, joints: Mapping[str, float] | Aim, straight: bool = False,
                 base: np.ndarray | None = None, duration: float | None = None) -> list[Clamp]:
        """Move the named joints to ``joints`` (clamped); the others keep their last target
        (or go to ``base``'s, every joint in P order: the guard's goal past a waypoint).

        ``straight``: phase-synchronised, so a move from rest follows the straight line in
        joint space (what the guard checked). ``duration``: arrive no sooner (a score's
        keyframe time; later when the limits allow no quicker). Unknown joint names
        (KeyError) and non-finite values (ValueError) change nothing.
        """
        aim = joints if isinstance(joints, Aim) else self.aim(joints)
        goal = (self.target if base is None else base).copy()
        goal[aim.index] = aim.values
        clamped = self.clamped
        if clamped:
            for name in aim.names:
                clamped.pop(name, None)
        if aim.beyond:
            clamped.update(aim.beyond)
        if self.dof:
            self.generator.go_to(goal, Synchronization.Phase if straight else Synchronization.Time,
                                 duration)
        return list(aim.clamps)

    def go_to(self, q: np.ndarray) -> None:
        """Straight (phase-synchronised) to ``q``, every joint, already inside the limits (the
        guard's waypoints); what was clamped stays reported."""
        if self.dof:
            self.generator.go_to(q, Synchronization.Phase)

    def course(self, brake_after: float, every: float) -> np.ndarray:
        """Where the motion just planned takes the joints if it brakes ``brake_after`` s from
        now: positions every ``every`` s, the last where they come to rest (``Otg.course``)."""
        return self.generator.course(brake_after, every)

    def reset(self, q: Values) -> None:
        """At rest at ``q`` (where the body was found), held there."""
        if self.dof:
            self.generator.reset(q)

    def stop(self) -> None:
        """Brake every joint to rest where it is, jerk-limited (the fastest stop the limits allow).

        The targets become wherever the joints come to rest.
        """
        if self.dof:
            self.generator.brake()

    def step(self) -> None:
        """Advance one control cycle along the current trajectory."""
        self.generator.step()
