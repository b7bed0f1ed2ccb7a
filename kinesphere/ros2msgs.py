"""The few ROS 2 messages kinesphere reads and writes, built and read in one place.

Messages are rosbags dataclasses (:func:`kinesphere.rmw_zenoh.message_class`); numeric
sequences are float64 numpy arrays as rosbags wants them. Readers check what a peer could get
wrong (lengths that disagree, non-finite numbers) and raise ``malformed`` naming the field.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, Final, NamedTuple

import numpy as np

from kinesphere.errors import KinesphereError
from kinesphere.rmw_zenoh import message_class

JOINT_STATE: Final = "sensor_msgs/msg/JointState"
JOY: Final = "sensor_msgs/msg/Joy"
TF_MESSAGE: Final = "tf2_msgs/msg/TFMessage"
STRING: Final = "std_msgs/msg/String"
JOINT_TRAJECTORY: Final = "trajectory_msgs/msg/JointTrajectory"
FLOAT64_MULTI_ARRAY: Final = "std_msgs/msg/Float64MultiArray"
TWIST: Final = "geometry_msgs/msg/Twist"
TWIST_STAMPED: Final = "geometry_msgs/msg/TwistStamped"
ODOMETRY: Final = "nav_msgs/msg/Odometry"


def _f64(values: Sequence[float]) -> np.ndarray:
    return np.asarray(values, dtype=np.float64)


def stamp(ns: int) -> Any:
    """``builtin_interfaces/msg/Time`` of a ``time.time_ns()`` value."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return message_class("builtin_interfaces/msg/Time")(sec=sec, nanosec=nanosec)


def duration(seconds: float) -> Any:
    """``builtin_interfaces/msg/Duration`` of a non-negative number of seconds."""
    sec, nanosec = divmod(round(max(0.0, seconds) * 1e9), 1_000_000_000)
    return message_class("builtin_interfaces/msg/Duration")(sec=sec, nanosec=nanosec)


def header(stamp_ns: int, frame_id: str = "") -> Any:
    return message_class("std_msgs/msg/Header")(stamp=stamp(stamp_ns), frame_id=frame_id)


def joint_state(names: Sequence[str], position: Sequence[float], velocity: Sequence[float],
                stamp_ns: int, frame_id: str = "") -> Any:
    """A JointState; ``velocity`` may be empty (unknown)."""
    return message_class(JOINT_STATE)(
        header=header(stamp_ns, frame_id), name=list(names), position=_f64(position),
        velocity=_f64(velocity), effort=_f64(()),
    )


def transform(parent: str, child: str, xyz: Sequence[float] | np.ndarray,
              xyzw: Sequence[float] | np.ndarray, stamp_ns: int) -> Any:
    """A TransformStamped: ``child`` at ``xyz`` turned by the unit quaternion ``xyzw`` (ROS
    order) in ``parent``."""
    geo = "geometry_msgs/msg/"
    x, y, z = (float(v) for v in xyz)
    qx, qy, qz, qw = (float(v) for v in xyzw)
    return message_class(f"{geo}TransformStamped")(
        header=header(stamp_ns, parent), child_frame_id=child,
        transform=message_class(f"{geo}Transform")(
            translation=message_class(f"{geo}Vector3")(x=x, y=y, z=z),
            rotation=message_class(f"{geo}Quaternion")(x=qx, y=qy, z=qz, w=qw),
        ),
    )


def planar(x: float, y: float, yaw: float) -> tuple[tuple[float, float, float],
                                                     tuple[float, float, float, float]]:
    """``(xyz, xyzw)`` of a pose on the floor: at ``(x, y)``, turned by ``yaw`` about z."""
    return (x, y, 0.0), (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


def tf_message(transforms: Sequence[Any]) -> Any:
    return message_class(TF_MESSAGE)(transforms=list(transforms))


class TfTemplate:
    """The CDR of a TFMessage whose frames stay the same and whose numbers change: laid out
    once by rosbags, then only the stamps, translations and rotations are written in place
    (about 20x quicker than building and serialising the message again, for a bridge that
    sends every robot's frames with every state). The layout is found, not assumed: rosbags
    serialises the message with a distinct marker in every numeric field, whose bytes are then
    located; the test suite checks the result against rosbags' own serialisation."""

    def __init__(self, pairs: Sequence[tuple[str, str]]) -> None:
        from kinesphere.rmw_zenoh import serialize

        n = len(pairs)
        marks = np.arange(1, 7 * n + 1, dtype=np.float64).reshape(n, 7) * 1.000_123 + 1e9
        secs = 0x5A5A0000 + np.arange(n)
        nsecs = 0x2A2A0000 + np.arange(n)
        msg = tf_message([transform(p, c, marks[k, :3], marks[k, 3:], 0)
                          for k, (p, c) in enumerate(pairs)])
        for k, t in enumerate(msg.transforms):
            t.header.stamp.sec, t.header.stamp.nanosec = int(secs[k]), int(nsecs[k])
        raw = serialize(msg, TF_MESSAGE)
        self.size = len(raw)
        self._template = bytes(raw)
        self._floats = np.array([_find(raw, np.float64(v).tobytes(), 8) for v in marks.ravel()])
        self._secs = np.array([_find(raw, np.int32(v).tobytes(), 4) for v in secs])
        self._nsecs = np.array([_find(raw, np.uint32(v).tobytes(), 4) for v in nsecs])
        self.count = n

    def encode(self, stamp_ns: int, xyz: np.ndarray, xyzw: np.ndarray) -> bytes:
        """The message's CDR with every transform stamped ``stamp_ns``, transform ``k`` at
        ``xyz[k]`` turned by the unit quaternion ``xyzw[k]`` (ROS order)."""
        buf = bytearray(self._template)
        body = memoryview(buf)[4:4 + (len(buf) - 4) // 8 * 8]
        np.frombuffer(body, dtype="<f8")[self._floats] = np.concatenate(
            [np.asarray(xyz, float).reshape(-1, 3), np.asarray(xyzw, float).reshape(-1, 4)],
            axis=1).ravel()
        ints = memoryview(buf)[4:4 + (len(buf) - 4) // 4 * 4]
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        view = np.frombuffer(ints, dtype="<u4")
        view[self._secs] = sec & 0xFFFFFFFF
        view[self._nsecs] = nanosec
        return bytes(buf)


def _find(raw: bytes, pattern: bytes, size: int) -> int:
    """The index (in ``size``-byte units after the 4-byte CDR header) of the one place
    ``pattern`` sits; a layout where it is not exactly once is an internal error."""
    at = raw.find(pattern)
    if at < 4 or raw.find(pattern, at + 1) != -1 or (at - 4) % size:
        raise KinesphereError("internal", "TF template: a numeric field was not found once")
    return (at - 4) // size


def tf_planar(parent: str, child: str, x: float, y: float, yaw: float, stamp_ns: int) -> Any:
    """A TFMessage with one transform: ``child`` at ``(x, y)`` turned by ``yaw`` in ``parent``."""
    return tf_message([transform(parent, child, *planar(x, y, yaw), stamp_ns)])


def twist(vx: float, vy: float, wz: float) -> Any:
    """A body-frame Twist (m/s, m/s, rad/s), what a base controller's ``cmd_vel`` takes."""
    vec = message_class("geometry_msgs/msg/Vector3")
    return message_class(TWIST)(linear=vec(x=float(vx), y=float(vy), z=0.0),
                                angular=vec(x=0.0, y=0.0, z=float(wz)))


def twist_stamped(vx: float, vy: float, wz: float, stamp_ns: int, frame_id: str = "") -> Any:
    """A TwistStamped, what Jazzy's diff_drive_controller requires on ``cmd_vel``."""
    return message_class(TWIST_STAMPED)(header=header(stamp_ns, frame_id),
                                        twist=twist(vx, vy, wz))


def odometry(frame: str, child: str, pose: Sequence[float], velocity: Sequence[float],
             stamp_ns: int) -> Any:
    """An Odometry of a planar base: ``pose`` ``(x, y, yaw)`` in ``frame``, ``velocity``
    ``(vx, vy, wz)`` in ``child`` (the base's own frame), covariances unknown (zero)."""
    geo = "geometry_msgs/msg/"
    xyz, xyzw = planar(*pose)
    pose_msg = message_class(f"{geo}Pose")(
        position=message_class(f"{geo}Point")(x=xyz[0], y=xyz[1], z=0.0),
        orientation=message_class(f"{geo}Quaternion")(x=0.0, y=0.0, z=xyzw[2], w=xyzw[3]),
    )
    return message_class(ODOMETRY)(
        header=header(stamp_ns, frame), child_frame_id=child,
        pose=message_class(f"{geo}PoseWithCovariance")(pose=pose_msg, covariance=_f64([0.0] * 36)),
        twist=message_class(f"{geo}TwistWithCovariance")(twist=twist(*velocity),
                                                         covariance=_f64([0.0] * 36)),
    )


def string(text: str) -> Any:
    return message_class(STRING)(data=text)


def joint_trajectory(names: Sequence[str], position: Sequence[float],
                     velocity: Sequence[float], time_from_start: float) -> Any:
    """A one-point JointTrajectory with a zero stamp ("start now"), as a streaming client
    sends to ros2_control's joint_trajectory_controller."""
    point = message_class("trajectory_msgs/msg/JointTrajectoryPoint")(
        positions=_f64(position), velocities=_f64(velocity), accelerations=_f64(()),
        effort=_f64(()), time_from_start=duration(time_from_start),
    )
    return message_class(JOINT_TRAJECTORY)(header=header(0), joint_names=list(names),
                                           points=[point])


def float64_multi_array(values: Sequence[float]) -> Any:
    """A Float64MultiArray with no layout, what a forward_command_controller reads."""
    layout = message_class("std_msgs/msg/MultiArrayLayout")(dim=[], data_offset=0)
    return message_class(FLOAT64_MULTI_ARRAY)(layout=layout, data=_f64(values))


class Joints(NamedTuple):
    """Names and positions (and velocities, possibly empty) read from a message."""

    names: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    stamp_ns: int


def read_joint_state(msg: Any) -> Joints:
    """Names, positions and velocities of a JointState, checked."""
    names = tuple(str(n) for n in msg.name)
    pos = tuple(float(v) for v in msg.position)
    vel = tuple(float(v) for v in msg.velocity)
    if len(pos) != len(names) or (vel and len(vel) != len(names)):
        raise KinesphereError(
            "malformed",
            f"JointState has {len(names)} names, {len(pos)} positions, {len(vel)} velocities",
        )
    if len(set(names)) != len(names):
        raise KinesphereError("malformed", "JointState names a joint twice")
    if not all(math.isfinite(v) for v in (*pos, *vel)):
        raise KinesphereError("malformed", "JointState carries a non-finite number")
    t = msg.header.stamp
    return Joints(names, pos, vel, int(t.sec) * 1_000_000_000 + int(t.nanosec))


def read_joy(msg: Any) -> tuple[tuple[float, ...], tuple[int, ...]]:
    """Axes (finite, clamped to -1..1) and buttons of a Joy message."""
    axes = tuple(float(v) for v in msg.axes)
    if not all(math.isfinite(v) for v in axes):
        raise KinesphereError("malformed", "Joy carries a non-finite axis")
    return tuple(max(-1.0, min(1.0, v)) for v in axes), tuple(int(b) for b in msg.buttons)


def read_odometry(msg: Any) -> tuple[float, float, float]:
    """The planar pose ``(x, y, yaw)`` of an Odometry (yaw from its orientation), checked."""
    p = msg.pose.pose.position
    o = msg.pose.pose.orientation
    values = (float(p.x), float(p.y), float(o.x), float(o.y), float(o.z), float(o.w))
    if not all(math.isfinite(v) for v in values):
        raise KinesphereError("malformed", "Odometry carries a non-finite number")
    x, y, qx, qy, qz, qw = values
    if abs(math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw) - 1.0) > 1e-3:
        raise KinesphereError("malformed", "Odometry orientation is not a unit quaternion")
    yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
    return x, y, yaw
