"""``--body ros2`` on a mobile platform: Twist out on cmd_vel (clamped to the base's limits),
Odometry in as the base pose, no odometry as a fault that stops the base.

The ROS side is ``support.ros2`` (rmw_zenoh's format written with f-strings, rosbags'
own type store, zenoh-ext attachments); the body's clock is the test's, so staleness is
exercised without sleeping.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__Twist as Twist
from rosbags.typesys.stores.ros2_jazzy import geometry_msgs__msg__TwistStamped as TwistStamped

from kinesphere import zconfig
from kinesphere.errors import KinesphereError
from kinesphere.platforms.platform import load_platform
from kinesphere.robots.agent.options import Ros2BodyOptions
from kinesphere.robots.agent.ros2_body import Ros2Body
from support.clock import ManualClock
from support.ros2 import JAZZY, RosPublisher, RosTap
from support.wait import until

NS = "/pk"


def _joint_state(names: list[str], q: list[float]) -> object:
    t = JAZZY.types
    sec, ns = divmod(time.time_ns(), 1_000_000_000)
    return t["sensor_msgs/msg/JointState"](
        header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](
            sec=sec, nanosec=ns), frame_id=""),
        name=names, position=np.array(q), velocity=np.array([]), effort=np.array([]))


def _odometry(x: float, y: float, yaw: float) -> object:
    t = JAZZY.types
    g = "geometry_msgs/msg/"
    return t["nav_msgs/msg/Odometry"](
        header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](
            sec=0, nanosec=0), frame_id="odom"), child_frame_id="base_link",
        pose=t[f"{g}PoseWithCovariance"](pose=t[f"{g}Pose"](
            position=t[f"{g}Point"](x=x, y=y, z=0.0),
            orientation=t[f"{g}Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2),
                                            w=math.cos(yaw / 2))), covariance=np.zeros(36)),
        twist=t[f"{g}TwistWithCovariance"](twist=t[f"{g}Twist"](
            linear=t[f"{g}Vector3"](x=0.0, y=0.0, z=0.0),
            angular=t[f"{g}Vector3"](x=0.0, y=0.0, z=0.0)), covariance=np.zeros(36)))


def test_mobile_base_over_ros2() -> None:
    platform = load_platform("packbot")
    spec = platform.base
    names = list(platform.joint_names)
    q = platform.neutral_vector().tolist()
    options = Ros2BodyOptions(namespace=NS, start_timeout_s=1.0)
    with zconfig.loopback_pair() as (ros, ours):
        states = RosPublisher(ros, 0, f"{NS}/joint_states", "sensor_msgs/msg/JointState")
        odom = RosPublisher(ros, 0, f"{NS}/odom", "nav_msgs/msg/Odometry", entity_id=902)
        cmd_vel = RosTap(ros, 0, f"{NS}/cmd_vel", Twist)
        stop = threading.Event()

        def broadcaster() -> None:  # the robot's joint_state_broadcaster, at 50 Hz
            while not stop.wait(0.02):
                states.put(_joint_state(names, q))

        thread = threading.Thread(target=broadcaster, daemon=True)
        thread.start()
        try:
            with pytest.raises(KinesphereError, match=f"no odometry on {NS}/odom .* mobile"):
                Ros2Body(platform, 0.01, ours, options)
            clock = ManualClock(100.0)
            odom_thread_stop = threading.Event()

            def base_controller() -> None:  # the base's odometry, at 50 Hz
                while not odom_thread_stop.wait(0.02):
                    odom.put(_odometry(1.5, -0.5, 3.0))

            ot = threading.Thread(target=base_controller, daemon=True)
            ot.start()
            body = Ros2Body(platform, 0.01, ours, options, clock=clock)  # waits for odometry
            assert body.read().base_pose == pytest.approx((1.5, -0.5, 3.0))
            # a command past the platform's limits goes out clamped, without sideways speed
            body.command(np.array(q), (10.0, 3.0, -20.0))
            body.step()
            t = cmd_vel.wait(lambda m: m.linear.x > 0, "a Twist").msg
            assert math.isclose(t.linear.x, spec.max_speed) and t.linear.y == 0.0
            assert math.isclose(t.angular.z, -spec.max_yaw_rate)
            # odometry stops: a fault naming it, and the base is sent a zero Twist
            odom_thread_stop.set()
            ot.join(timeout=5)
            # a last odometry of its own pose: once the body has it, none is still on its way
            # (one would be stamped after the clock moves, and be fresh)
            odom.put(_odometry(1.25, -0.5, 3.0))
            until(lambda: body.read().base_pose[0] == 1.25, 30.0, "the last odometry")
            clock.now += options.timeout_s + 0.1
            assert body.wait_states(body.states + 2, 30.0), "joint states go on"
            with pytest.raises(KinesphereError, match=f"no odometry on {NS}/odom for"):
                body.step()
            body.halt()
            zero = cmd_vel.wait(lambda m: m.linear.x == 0.0, "the zero Twist").msg
            assert (zero.linear.x, zero.linear.y, zero.angular.z) == (0.0, 0.0, 0.0)
            body.close()
            # Jazzy's diff_drive_controller takes TwistStamped, stamped now, in the base frame
            stamped = RosTap(ros, 0, f"{NS}/cmd_vel", TwistStamped)
            ot = threading.Thread(target=base_controller, daemon=True)
            odom_thread_stop.clear()
            ot.start()
            body = Ros2Body(platform, 0.01, ours, Ros2BodyOptions(
                namespace=NS, start_timeout_s=5.0, cmd_vel_stamped=True))
            body.command(np.array(q), (0.2, 0.0, 0.1))
            body.step()
            ts = stamped.wait(lambda m: m.twist.linear.x > 0, "a TwistStamped").msg
            assert (ts.twist.linear.x, ts.twist.angular.z) == (0.2, 0.1)
            assert ts.header.frame_id == platform.eurdf.root_link
            assert abs(ts.header.stamp.sec - time.time()) < 60
            body.close()
            odom_thread_stop.set()
            ot.join(timeout=5)
            stamped.close()
        finally:
            stop.set()
            thread.join(timeout=5)
            for e in (states, odom, cmd_vel):
                e.close()
