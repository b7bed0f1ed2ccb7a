"""A ros2_control robot over rmw_zenoh as the agent's body (``--body ros2``), no ROS installed.

The agent keeps everything that makes motion safe — its loop, Ruckig, clamping, deadman, TTL,
e-stop — and this body only carries it to a real robot and back:

- it reads ``<NS>/joint_states`` (``sensor_msgs/msg/JointState``, e.g. from ros2_control's
  joint_state_broadcaster), picking the eURDF's joints by name (other names are ignored);
  velocities not measured are estimated from consecutive positions and their stamps;
- it streams the Ruckig setpoint to the robot's controller at ``publish_rate``: a one-point
  ``trajectory_msgs/msg/JointTrajectory`` (positions and velocities, ``time_from_start`` one
  stream period, stamp zero = "now") on ``<NS>/<controller>/joint_trajectory`` for a
  joint_trajectory_controller, or a ``std_msgs/msg/Float64MultiArray`` of positions in the
  controller's joint order on ``<NS>/<controller>/commands`` for a forward position controller.

A mobile platform's base is driven as a ROS base is: the body-frame velocity the agent
commands goes out as ``geometry_msgs/msg/Twist`` on ``<NS>/cmd_vel`` with every setpoint
(clamped to the platform's top speed and yaw rate; no sideways speed for a diff or skid
base; ``TwistStamped`` with ``cmd_vel_stamped``, as Jazzy's diff_drive_controller wants),
and ``nav_msgs/msg/Odometry`` from ``<NS>/odom`` is the base pose the agent reads.

Every target is clamped again to the eURDF's hard limits before it leaves. Faults are raised
from :meth:`Ros2Body.step` as ``KinesphereError`` naming the problem — joint states (or a
mobile base's odometry) that stop arriving for ``timeout_s``, or that lack an eURDF joint — so
the agent reports ``error`` with that text and holds; while they last, no joint setpoint is
streamed (a joint_trajectory_controller holds the end of its last point, a forward controller
its last command) and the base is sent a zero Twist. The first joint state (and odometry) must
arrive within ``start_timeout_s`` of start-up and name every joint of P, or the agent does not
start.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence

import numpy as np
import zenoh

from kinesphere import ros2msgs as rm
from kinesphere.errors import KinesphereError
from kinesphere.platforms.platform import Platform
from kinesphere.robots.agent.body import Body, Reading
from kinesphere.robots.agent.options import Ros2BodyOptions
from kinesphere.ros2node import Node

log = logging.getLogger(__name__)

DEFAULT_CONTROLLERS = {"trajectory": "joint_trajectory_controller",
                       "forward": "forward_position_controller"}


class Ros2Body(Body):
    """Joint states in, controller commands out, over ``session`` in rmw_zenoh's format."""

    def __init__(self, platform: Platform, dt: float, session: zenoh.Session,
                 options: Ros2BodyOptions | None = None, node_name: str = "kinesphere_agent",
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.platform = platform
        self.dt = dt
        self.options = o = options or Ros2BodyOptions()
        self._clock = clock
        names = self.joint_names
        lim = self.limits
        self._lower = np.array([limit.lower for limit in lim])
        self._upper = np.array([limit.upper for limit in lim])
        self.order = tuple(o.joints) or names
        unknown = sorted(set(self.order) - set(names))
        if unknown or len(set(self.order)) != len(self.order):
            raise KinesphereError("malformed", f"--ros2-joints must name each joint of P once; "
                                  f"unknown or repeated: {', '.join(unknown) or 'repeats'}")
        self._out = np.array([names.index(j) for j in self.order], dtype=int)
        self.every = max(1, round(1.0 / (o.publish_rate * dt)))
        self.node = Node(session, node_name, o.namespace, o.domain, o.distro)
        controller = o.controller or DEFAULT_CONTROLLERS[o.interface]
        self._lock = threading.Condition()
        self._latest: tuple[float, np.ndarray, np.ndarray] | None = None
        self._mismatch = ""
        self._prev: tuple[int, np.ndarray] | None = None
        self.states = 0
        self.state_topic = self.node.resolve("joint_states")
        self.node.subscription("joint_states", rm.JOINT_STATE, self._on_state)
        if o.interface == "trajectory":
            self.pub = self.node.publisher(f"{controller}/joint_trajectory", rm.JOINT_TRAJECTORY)
        else:
            self.pub = self.node.publisher(f"{controller}/commands", rm.FLOAT64_MULTI_ARRAY)
        self.command_topic = self.pub.topic
        self._target: np.ndarray | None = None
        self._sent: np.ndarray | None = None
        self._steps = 0
        base = platform.base
        self.mobile = base.mobile
        self._twist = (0.0, 0.0, 0.0)
        self._odom: tuple[float, tuple[float, float, float]] | None = None
        self._max_speed = base.max_speed
        self._max_yaw_rate = base.max_yaw_rate
        self._lateral = base.holonomic
        if self.mobile:
            self.odom_topic = self.node.resolve(o.odom)
            self.node.subscription(o.odom, rm.ODOMETRY, self._on_odom)
            self.cmd_vel = self.node.publisher(
                o.cmd_vel, rm.TWIST_STAMPED if o.cmd_vel_stamped else rm.TWIST)
        try:
            first = self._wait_first()
        except KinesphereError:
            self.node.close()
            raise
        self._q = first
        self._qd = np.zeros_like(first)
        log.info("ROS 2 body: %d joints from %s, commands to %s", len(names), self.state_topic,
                 self.command_topic)

    # --- joint states (Zenoh thread) ----------------------------------------------------------

    def _on_state(self, msg: object) -> None:
        joints = rm.read_joint_state(msg)
        index = {n: i for i, n in enumerate(joints.names)}
        missing = [j for j in self.joint_names if j not in index]
        with self._lock:
            if missing:
                self._mismatch = (f"joint states on {self.state_topic} lack eURDF joints "
                                  f"{', '.join(missing[:8])}{' ...' if len(missing) > 8 else ''}"
                                  f" (they name {', '.join(joints.names[:8])})")
                self._lock.notify_all()
                return
            q = np.array([joints.position[index[j]] for j in self.joint_names])
            if joints.velocity:
                qd = np.array([joints.velocity[index[j]] for j in self.joint_names])
            else:  # not measured: from the last two positions and their stamps
                qd = np.zeros_like(q)
                if self._prev is not None and 0 < joints.stamp_ns - self._prev[0] < 1e9:
                    qd = (q - self._prev[1]) / ((joints.stamp_ns - self._prev[0]) * 1e-9)
            self._prev = (joints.stamp_ns, q)
            self._mismatch = ""
            self._latest = (self._clock(), q, qd)
            self.states += 1
            self._lock.notify_all()

    def _on_odom(self, msg: object) -> None:
        x, y, yaw = rm.read_odometry(msg)
        with self._lock:
            self._odom = (self._clock(), (x, y, yaw))
            self._lock.notify_all()

    def wait_states(self, count: int, timeout: float) -> bool:
        """Wait until ``count`` joint states have arrived in total (tests)."""
        with self._lock:
            return self._lock.wait_for(lambda: self.states >= count, timeout)

    def _wait_first(self) -> np.ndarray:
        o = self.options
        with self._lock:
            self._lock.wait_for(lambda: (self._latest is not None and (
                not self.mobile or self._odom is not None)) or bool(self._mismatch),
                o.start_timeout_s)
            if self._latest is None:
                raise KinesphereError(
                    "unavailable" if not self._mismatch else "malformed",
                    self._mismatch or f"no joint states on {self.state_topic} (domain "
                    f"{o.domain}) within {o.start_timeout_s:g} s: is the "
                    "robot's joint_state_broadcaster running and on the same Zenoh router?",
                )
            if self.mobile and self._odom is None:
                raise KinesphereError(
                    "unavailable", f"no odometry on {self.odom_topic} (domain {o.domain}) "
                    f"within {o.start_timeout_s:g} s: {self.platform.name} has a mobile base; "
                    "is its base controller publishing nav_msgs/msg/Odometry there?")
            return self._latest[1].copy()

    def _fresh(self) -> tuple[np.ndarray, np.ndarray]:
        """The latest joint state, or the fault that makes it unusable."""
        with self._lock:
            latest, mismatch = self._latest, self._mismatch
        if mismatch:
            raise KinesphereError("malformed", mismatch)
        assert latest is not None
        now = self._clock()
        age = now - latest[0]
        if age > self.options.timeout_s:
            raise KinesphereError(
                "unavailable", f"no joint states on {self.state_topic} for {age:.1f} s "
                f"(limit {self.options.timeout_s:g} s)")
        if self.mobile:
            assert self._odom is not None
            age = now - self._odom[0]
            if age > self.options.timeout_s:
                raise KinesphereError(
                    "unavailable", f"no odometry on {self.odom_topic} for {age:.1f} s "
                    f"(limit {self.options.timeout_s:g} s)")
        return latest[1], latest[2]

    # --- the Body seam (control thread) -------------------------------------------------------

    def read(self) -> Reading:
        with self._lock:
            latest = self._latest
            odom = self._odom
        if latest is not None:
            self._q, self._qd = latest[1], latest[2]
        pose = (0.0, 0.0, 0.0)
        if odom is not None:
            x, y, yaw = odom[1]
            pose = (x, y, math.atan2(math.sin(yaw), math.cos(yaw)))
        return Reading(self._q.copy(), self._qd.copy(), pose)

    def command(self, q: np.ndarray, base_twist: Sequence[float] | np.ndarray) -> None:
        self._target = np.clip(np.asarray(q, dtype=float), self._lower, self._upper)
        if self.mobile:
            vx, vy, wz = (float(v) for v in base_twist)
            if not self._lateral:
                vy = 0.0
            speed = math.hypot(vx, vy)
            if speed > self._max_speed:  # the planner's limit, enforced again on the way out
                vx, vy = vx * self._max_speed / speed, vy * self._max_speed / speed
            wz = min(max(wz, -self._max_yaw_rate), self._max_yaw_rate)
            self._twist = (vx, vy, wz)

    def step(self) -> None:
        self._fresh()
        self._steps += 1
        if self._target is not None and self._steps % self.every == 0:
            self._send(self._target)
            if self.mobile:
                self._send_twist(*self._twist)

    def halt(self) -> None:
        """Hold where the robot is now (its latest joint state, a zero base velocity),
        streamed at once; the zero Twist goes out even when the data is stale."""
        if self.mobile:
            self._twist = (0.0, 0.0, 0.0)
            self._send_twist(0.0, 0.0, 0.0)
        with self._lock:
            latest = self._latest
        if latest is None:
            return
        self._target = np.clip(latest[1], self._lower, self._upper)
        self._sent = None
        try:
            self._fresh()
        except KinesphereError:
            return  # stale or mismatched: do not stream from old data
        self._send(self._target)

    def _send_twist(self, vx: float, vy: float, wz: float) -> None:
        if self.options.cmd_vel_stamped:
            self.cmd_vel.put(rm.twist_stamped(vx, vy, wz, time.time_ns(),
                                              self.platform.eurdf.root_link))
        else:
            self.cmd_vel.put(rm.twist(vx, vy, wz))

    def _send(self, target: np.ndarray) -> None:
        period = self.every * self.dt
        if not np.isfinite(target).all():
            raise KinesphereError("internal", "non-finite joint target")
        if self.options.interface == "trajectory":
            velocity = (np.zeros_like(target) if self._sent is None
                        else (target - self._sent) / period)
            out = self._out
            self.pub.put(rm.joint_trajectory([self.joint_names[i] for i in out], target[out],
                                             velocity[out], period))
        else:
            self.pub.put(rm.float64_multi_array(target[self._out]))
        self._sent = target

    def close(self) -> None:
        self.node.close()


def make_ros2_body(platform: Platform, dt: float, session: zenoh.Session,
                   options: Ros2BodyOptions, robot_id: str) -> Ros2Body:
    """The body ``--body ros2`` makes; its node is named after the robot."""
    from kinesphere.rmw_zenoh import ros_name

    if not math.isfinite(dt) or dt <= 0:
        raise KinesphereError("malformed", f"control period must be > 0 s, got {dt}")
    return Ros2Body(platform, dt, session, options, node_name=f"kinesphere_{ros_name(robot_id)}")
