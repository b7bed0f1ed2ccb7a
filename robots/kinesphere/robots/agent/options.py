"""How an agent runs: the options ``kinesphere agent`` and tests give :class:`Agent`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import DEFAULT_PREFIX
from kinesphere.rmw_zenoh import check_distro
from kinesphere.sizes import MAX_TRANSLATION

DEFAULT_MARGIN = 0.01
"""Target clamp margin inside each limit, rad (or m); shrunk for joints with a tiny range
(``trajectory.clamp_margin``). Here, not in ``trajectory``, so that a command line's parser
imports neither NumPy nor Ruckig."""
ROS2_INTERFACES = ("trajectory", "forward")
BODY_KINDS: Final = ("mujoco", "ros2")
"""The bodies ``--body`` may name, the default first; ``bodies.BODIES`` makes each."""


@dataclass(frozen=True)
class Ros2BodyOptions:
    """``--body ros2``: where the ros2_control robot is and how it takes commands.

    ``namespace`` and ``domain`` of its topics; ``interface`` ``trajectory`` (a
    joint_trajectory_controller: JointTrajectory on ``<controller>/joint_trajectory``) or
    ``forward`` (a forward position controller: Float64MultiArray on ``<controller>/commands``
    in ``joints`` order, default P's); ``controller`` defaults to joint_trajectory_controller or
    forward_position_controller. A mobile platform's base takes ``geometry_msgs/msg/Twist`` on
    ``cmd_vel`` and reports ``nav_msgs/msg/Odometry`` on ``odom`` (both relative to the
    namespace). No joint state (or, for a mobile base, odometry) for ``timeout_s`` is an error;
    the first must come within ``start_timeout_s``. The setpoint stream runs at
    ``publish_rate`` Hz. ``distro`` is the ROS 2 distribution whose rmw_zenoh keys it writes.
    """

    namespace: str = "/"
    domain: int = 0
    interface: str = "trajectory"
    controller: str = ""
    joints: tuple[str, ...] = ()
    timeout_s: float = 0.5
    start_timeout_s: float = 10.0
    publish_rate: float = 100.0
    cmd_vel: str = "cmd_vel"
    cmd_vel_stamped: bool = False
    """Send ``geometry_msgs/msg/TwistStamped`` instead (Jazzy's diff_drive_controller)."""
    odom: str = "odom"
    distro: str = "jazzy"

    def __post_init__(self) -> None:
        check_distro(self.distro)
        if self.interface not in ROS2_INTERFACES:
            raise KinesphereError("malformed", f"ROS 2 interface {self.interface!r}; valid: "
                                  f"{', '.join(ROS2_INTERFACES)}")
        for what, v in (("timeout", self.timeout_s), ("start timeout", self.start_timeout_s),
                        ("publish rate", self.publish_rate)):
            if not (math.isfinite(v) and v > 0):
                raise KinesphereError("malformed", f"ROS 2 {what} must be > 0, got {v}")


@dataclass(frozen=True)
class AgentOptions:
    """How an agent runs; the single source of its defaults (``kinesphere agent`` reads them).

    ``control_rate`` (the control and physics loop) and ``state_rate`` in Hz, ``speed`` (robot
    seconds per wall second, 0 = unpaced), key ``prefix``, ``groups`` it obeys, databank query
    timeout, joint-limit clamp ``margin``, the ``body`` it drives (one of :data:`BODY_KINDS`,
    each made by ``bodies.BODIES``; ``ros2`` reads ``ros2``), and the largest base translation
    one command may ask for (``max_translation_m``; a pose asking for more is refused with
    ``size_out_of_range`` and nothing moves), and ``strict_period``.
    """

    control_rate: float = 500.0
    state_rate: float = 50.0
    speed: float = 1.0
    prefix: str = DEFAULT_PREFIX
    groups: tuple[str, ...] = ()
    query_timeout_s: float = 1.0
    margin: float = DEFAULT_MARGIN
    body: str = BODY_KINDS[0]
    ros2: Ros2BodyOptions = Ros2BodyOptions()
    max_translation_m: float = MAX_TRANSLATION
    """By default as far as the ECL answers in one pose, so the robot and its databank agree
    (``docs/protocol.md``, "Bounds")."""
    strict_period: bool = False
    """Step only on the fixed schedule, so a command waits for the next tick (by default the
    loop runs the step that is due next as soon as a command arrives: ``pacing.py``)."""

    def __post_init__(self) -> None:
        checks = (
            (math.isfinite(self.control_rate) and self.control_rate > 0,
             f"control rate must be > 0 Hz, got {self.control_rate}"),
            (0 < self.state_rate <= self.control_rate,
             f"state rate must be in (0, control rate], got {self.state_rate}"),
            (math.isfinite(self.speed) and self.speed >= 0,
             f"speed must be >= 0 (0 = unpaced), got {self.speed}"),
            (self.query_timeout_s > 0, f"query timeout must be > 0, got {self.query_timeout_s}"),
            (self.margin >= 0, f"margin must be >= 0, got {self.margin}"),
            (math.isfinite(self.max_translation_m) and self.max_translation_m >= 0,
             f"max translation must be a distance >= 0 m, got {self.max_translation_m}"),
            (self.body in BODY_KINDS,
             f"unknown body {self.body!r}; valid: {', '.join(BODY_KINDS)}"),
        )
        for ok, message in checks:
            if not ok:
                raise KinesphereError("malformed", message)

    @property
    def publish_every(self) -> int:
        """Control steps between two published states (an agent's, and a fleet host's for
        all its robots)."""
        return max(1, round(self.control_rate / self.state_rate))
