"""The seam between the agent and a robot's body (after LeRobot's small ``Robot`` base class).

The agent owns the loop, the safety rules, the resolver, the trajectories and its Zenoh face; a
:class:`Body` only reads and commands. It takes, every control period, position targets for the
joints of P and a body-frame velocity for the base (what a real base's ``cmd_vel`` takes), and
:meth:`Body.step` either simulates that period (MuJoCo) or syncs with the hardware's cycle.
Bodies are chosen by name (``kinesphere agent --body mujoco``, the default) from
``bodies.BODIES``; a new kind of body registers a factory there.
"""

from __future__ import annotations

import abc
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, NamedTuple

if TYPE_CHECKING:  # the CLI reads BODIES for --help: no numpy, no URDF parser at import
    import numpy as np

    from kinesphere.eurdf import JointLimit
    from kinesphere.platforms.platform import Platform


AT_REST = (0.0, 0.0, 0.0)
"""The body-frame twist of a base at rest (``Body.command``: nothing to integrate)."""


class Reading(NamedTuple):
    """What a body measures: joint positions and velocities in P order (rad or m, rad/s or
    m/s) and the base's odometry ``(x m, y m, yaw rad)``, yaw in (-pi, pi]. (A named tuple:
    made at every state a robot publishes.)"""

    q: np.ndarray
    qd: np.ndarray
    base_pose: tuple[float, float, float]


class Body(abc.ABC):
    """A robot body stepped at ``1/dt`` Hz: read it, command it, step it, halt it."""

    platform: Platform
    dt: float

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The joints of P, in the order of every array a body takes or gives."""
        return self.platform.joint_names

    @property
    def limits(self) -> tuple[JointLimit, ...]:
        """Each joint's position and velocity limits (from the eURDF)."""
        return tuple(self.platform.eurdf.limits[j] for j in self.joint_names)

    @abc.abstractmethod
    def read(self) -> Reading:
        """The latest measurement (cheap: called several times per step)."""

    @abc.abstractmethod
    def command(self, q: np.ndarray, base_twist: Sequence[float] | np.ndarray) -> None:
        """Track joint positions ``q`` (P order) and body-frame base velocity
        ``(vx m/s, vy m/s, yaw rate rad/s)`` over the next period (a fixed base ignores it)."""

    @abc.abstractmethod
    def step(self) -> None:
        """Let one period pass: simulate it, or wait for the hardware's next cycle."""

    def simulate(self) -> None:
        """:meth:`step` as a fleet host calls it: on a helper thread, beside other bodies'
        and while the loop waits for its next tick, so it may touch nothing but this body
        (and gains most when it releases the GIL, as MuJoCo does). By default :meth:`step`."""
        self.step()

    def simulator(self) -> Callable[[], None]:
        """What does :meth:`simulate` with the least Python in between (a fleet host calls it
        for every body every tick); valid while the body keeps its model and data. By
        default :meth:`simulate` itself."""
        return self.simulate

    @abc.abstractmethod
    def halt(self) -> None:
        """Hold where the body is now, joints and base (when the trajectories cannot say)."""

    def contacts(self) -> list[tuple[str, str]]:
        """Pairs of links touching each other now (explains a blocked body); [] if unknown."""
        return []

    def touching(self) -> bool:
        """Whether any links touch now (asked every step while moving: keep it cheap)."""
        return bool(self.contacts())

    def close(self) -> None:  # noqa: B027 - optional: a simulation has nothing to release
        """Release the body."""
