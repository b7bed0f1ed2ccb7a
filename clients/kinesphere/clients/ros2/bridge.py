"""``kinesphere ros2 bridge``: every live kinesphere robot, seen by ROS 2 tools over rmw_zenoh.

An observer on the Zenoh network: it reads each robot's ``RobotState`` and its platform's
``BodyModel`` (from the databank) and republishes them as one ROS node (``kinesphere_bridge``)
speaking rmw_zenoh's wire format, so ``ros2 topic list``, RViz, Foxglove and ``ros2 bag``
see, for robot ``ID`` (``ID`` made a valid ROS name: ``baxter-1`` -> ``baxter_1``)::

    ID/joint_states       sensor_msgs/msg/JointState  every RobotState (names, q, qd)
    ID/robot_description  std_msgs/msg/String         the URDF (eURDF minus body_part labels),
                                                      reliable + transient local, depth 1
    ID/odom               nav_msgs/msg/Odometry       the base pose (and its rate of change)
    tf                    tf2_msgs/msg/TFMessage      odom -> ID/<URDF root link>, and every
                                                      moving joint's ID/<parent> -> ID/<child>
    tf_static             tf2_msgs/msg/TFMessage      every robot's fixed joints, one latched
                                                      message (transient local, depth 1)

That is what robot_state_publisher (with ``frame_prefix`` ``ID/``) and a base's odometry
would publish, so RViz shows every robot from the bridge alone. Like tf2's static broadcaster,
the node keeps one /tf_static message holding every fixed transform it knows, sent again when a
robot comes or goes, so a late joiner's one cached sample describes the whole fleet. Names are
relative to ``--namespace`` (``/`` by default, so ``/baxter_1/joint_states`` and ``/tf``). A
robot appears when its first state arrives and disappears (publishers and graph tokens
undeclared) when its liveliness token goes; a state of it that arrives after that (states and
tokens travel apart) is ignored until its token is back, so a robot that left is never bridged
again by its last state (``left``, bounded like the robots). Bodies are fetched on a worker
thread, never in a Zenoh callback; until a platform's body arrives its robots publish joint
states only (frames and the URDF come from the body). Bounded: at most ``max_robots`` robots,
states with more than ``MAX_SEQUENCE`` joints and URDFs larger than ``max_urdf_bytes`` are
refused with one log line, and so is a body that fails the eURDF's checks (its robots keep
their joint states; the other platforms are not held up).
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from kinesphere import ros2msgs as rm
from kinesphere.clients.options import BridgeOptions
from kinesphere.errors import KinesphereError
from kinesphere.joint_frames import JointFrames
from kinesphere.keyexpr import Keys
from kinesphere.lru import Lru
from kinesphere.protocol import BodyModel, RobotState, decode
from kinesphere.query import get_one
from kinesphere.rmw_zenoh import LATCHED, MAX_SEQUENCE, ros_name
from kinesphere.ros2node import Node, Publisher
from kinesphere.zconfig import undeclare

log = logging.getLogger(__name__)


@dataclass
class _Body:
    urdf: str
    root_link: str
    frames: JointFrames
    neutral: dict[str, float]


@dataclass
class _Robot:
    """The ROS face of one kinesphere robot."""

    robot_id: str
    ros_id: str
    platform: str
    joint_states: Publisher
    body: _Body | None = None
    description: Publisher | None = None
    odom: Publisher | None = None
    tf: rm.TfTemplate | None = None
    """Its /tf message (odom -> root, then the moving joints), numbers written per state."""
    last_base: tuple[int, float, float, float] | None = None
    """(stamp ns, x, y, yaw) of the last state, for the odometry's velocity."""
    published: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)
    """Held while its messages go out and while it closes: a publisher undeclared during a
    put on another thread raises in Zenoh."""
    closed: bool = False

    def close(self) -> None:
        with self.lock:
            self.closed = True
            for pub in (self.joint_states, self.description, self.odom):
                if pub is not None:
                    pub.close()

    def frame(self, link: str) -> str:
        """A link's TF frame: prefixed with the robot's ROS name, as robot_state_publisher's
        ``frame_prefix`` does."""
        return f"{self.ros_id}/{link}"


@dataclass
class BridgeStats:
    robots: int = 0
    states: int = 0
    late: int = 0
    """States of robots that had left, ignored."""
    refused: dict[str, int] = field(default_factory=dict)


class Bridge:
    """Republishes robots for ROS 2 until :meth:`close`."""

    def __init__(self, session: zenoh.Session, keys: Keys | None = None,
                 options: BridgeOptions | None = None) -> None:
        self.session = session
        self.keys = keys or Keys()
        self.options = options or BridgeOptions()
        self.node = Node(session, self.options.node, self.options.namespace, self.options.domain,
                         self.options.distro)
        self.tf = self.node.publisher("tf", rm.TF_MESSAGE)
        self.tf_static = self.node.publisher("tf_static", rm.TF_MESSAGE, LATCHED)
        self._static: dict[str, list[Any]] = {}
        self.stats = BridgeStats()
        self._robots: dict[str, _Robot] = {}
        self._bodies: dict[str, _Body] = {}
        self._wanted: queue.Queue[str | None] = queue.Queue()
        self._asked: set[str] = set()
        self._left: Lru[str, bool] = Lru(self.options.max_robots)
        """Robots whose liveliness token went, until it is back (module text)."""
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._worker = threading.Thread(target=self._fetch_bodies, name="ros2-bridge-bodies",
                                        daemon=True)
        self._worker.start()
        self._states = session.declare_subscriber(self.keys.state("*"), self._on_state)
        self._alive = session.liveliness().declare_subscriber(
            self.keys.alive_robot("*"), self._on_alive
        )

    # --- robots ------------------------------------------------------------------------------

    def robots(self) -> dict[str, str]:
        """kinesphere id -> ROS name of every robot bridged now."""
        with self._lock:
            return {r.robot_id: r.ros_id for r in self._robots.values()}

    def _refuse(self, what: str, message: str) -> None:
        n = self.stats.refused.get(what, 0) + 1
        self.stats.refused[what] = n
        if n == 1 or n % 100 == 0:
            log.warning("%s (%d so far)", message, n)

    def _robot(self, state: RobotState) -> _Robot | None:
        with self._lock:
            robot = self._robots.get(state.robot_id)
            if robot is not None or self._closed.is_set():
                return robot
            if state.robot_id in self._left:
                self.stats.late += 1
                return None
            if len(self._robots) >= self.options.max_robots:
                self._refuse("max_robots", f"robot {state.robot_id!r} not bridged: "
                             f"already {self.options.max_robots} robots")
                return None
            ros_id = ros_name(state.robot_id)
            if any(r.ros_id == ros_id for r in self._robots.values()):
                self._refuse("name_clash", f"robot {state.robot_id!r} not bridged: its ROS name "
                             f"{ros_id!r} is taken by another robot")
                return None
            robot = _Robot(state.robot_id, ros_id, state.platform,
                           self.node.publisher(f"{ros_id}/joint_states", rm.JOINT_STATE))
            self._robots[state.robot_id] = robot
            self.stats.robots = len(self._robots)
            body = self._bodies.get(state.platform)
            if body is not None:
                self._describe(robot, body)
            elif state.platform not in self._asked:
                self._asked.add(state.platform)
                self._wanted.put(state.platform)
        log.info("bridging robot %s (%s) as %s", state.robot_id, state.platform,
                 self.node.resolve(ros_id))
        return robot

    def _describe(self, robot: _Robot, body: _Body) -> None:
        """Publish the robot's URDF and fixed joints (latched) once its body is known, and
        start its odometry; called with the bridge's lock."""
        with robot.lock:
            if robot.closed:
                return
            robot.description = self.node.publisher(f"{robot.ros_id}/robot_description",
                                                     rm.STRING, LATCHED)
            robot.description.put(rm.string(body.urdf))
            frames = body.frames
            wxyz, xyz = frames.transforms(frames.vector(body.neutral))
            now = time.time_ns()
            fixed = [self._joint_tf(robot, body, i, wxyz, xyz, now)
                     for i in range(len(frames.names)) if not frames.moving[i]]
            if fixed:
                self._static[robot.robot_id] = fixed
                self._put_static()
            robot.odom = self.node.publisher(f"{robot.ros_id}/odom", rm.ODOMETRY)
            robot.tf = rm.TfTemplate(
                [(self.options.odom_frame, robot.frame(body.root_link))]
                + [(robot.frame(frames.parents[i]), robot.frame(frames.children[i]))
                   for i in range(len(frames.names)) if frames.moving[i]])
            robot.body = body  # last: a state published from now on has every publisher

    def _put_static(self) -> None:
        """The one /tf_static message: every robot's fixed transforms (with the lock)."""
        self.tf_static.put(rm.tf_message([t for ts in self._static.values() for t in ts]))

    @staticmethod
    def _joint_tf(robot: _Robot, body: _Body, i: int, wxyz: Any, xyz: Any, stamp_ns: int
                  ) -> Any:
        frames = body.frames
        w, x, y, z = wxyz[i].tolist()
        return rm.transform(robot.frame(frames.parents[i]), robot.frame(frames.children[i]),
                            xyz[i].tolist(), (x, y, z, w), stamp_ns)

    def _publish_body(self, robot: _Robot, state: RobotState) -> None:
        """TF (base pose and moving joints) and odometry of a robot whose body is known."""
        body = robot.body
        assert body is not None and robot.odom is not None
        frames = body.frames
        try:
            q = frames.q_from(state.joint_names, state.q, body.neutral)
        except ValueError:
            raise KinesphereError("malformed", f"state of {state.robot_id!r} has "
                                  f"{len(state.joint_names)} names and {len(state.q)} "
                                  "positions") from None
        stamp = state.stamp_ns
        x, y, yaw = state.base_pose
        root = robot.frame(body.root_link)
        wxyz, xyz = frames.transforms(q)
        base_xyz, base_xyzw = rm.planar(x, y, yaw)
        moving = frames.moving
        assert robot.tf is not None
        self.tf.put_cdr(robot.tf.encode(
            stamp, np.vstack([base_xyz, xyz[moving]]),
            np.vstack([base_xyzw, wxyz[moving][:, [1, 2, 3, 0]]])))
        velocity = (0.0, 0.0, 0.0)
        last = robot.last_base
        if last is not None and 0 < stamp - last[0] < 1_000_000_000:
            dt = (stamp - last[0]) * 1e-9
            dx, dy = x - last[1], y - last[2]
            c, s = math.cos(yaw), math.sin(yaw)  # world to the base's frame
            velocity = ((c * dx + s * dy) / dt, (-s * dx + c * dy) / dt,
                        math.remainder(yaw - last[3], math.tau) / dt)
        robot.last_base = (stamp, x, y, yaw)
        robot.odom.put(rm.odometry(self.options.odom_frame, root, (x, y, yaw), velocity, stamp))

    def _on_state(self, sample: zenoh.Sample) -> None:
        try:
            state = decode(sample.payload, RobotState)
        except KinesphereError as exc:
            self._refuse("malformed", f"bad state on {sample.key_expr}: {exc.message}")
            return
        if len(state.joint_names) > MAX_SEQUENCE:
            self._refuse("too_many_joints", f"state of {state.robot_id!r} has "
                         f"{len(state.joint_names)} joints (at most {MAX_SEQUENCE})")
            return
        robot = self._robot(state)
        if robot is None:
            return
        with robot.lock:
            if robot.closed:
                return
            try:
                robot.joint_states.put(
                    rm.joint_state(state.joint_names, state.q, state.qd, state.stamp_ns)
                )
                if robot.body is not None:
                    self._publish_body(robot, state)
            except KinesphereError as exc:
                self._refuse("malformed", exc.message)
                return
            except zenoh.ZError as exc:  # the session is closing
                log.debug("state of %s not republished: %s", state.robot_id, exc)
                return
            robot.published += 1
        self.stats.states += 1

    def _on_alive(self, sample: zenoh.Sample) -> None:
        try:
            robot_id = self.keys.robot_id_of(str(sample.key_expr))
        except KinesphereError:
            return
        if sample.kind != zenoh.SampleKind.DELETE:
            with self._lock:
                self._left.pop(robot_id)
            return
        with self._lock:
            self._left.put(robot_id, True)
            robot = self._robots.pop(robot_id, None)
            self.stats.robots = len(self._robots)
            if self._static.pop(robot_id, None) is not None and not self._closed.is_set():
                self._put_static()
        if robot is not None:
            robot.close()
            log.info("robot %s left; %s no longer published", robot_id, robot.ros_id)

    # --- bodies ------------------------------------------------------------------------------

    def _fetch_bodies(self) -> None:
        while not self._closed.is_set():
            platform = self._wanted.get()
            if platform is None:
                return
            try:
                body = self._fetch(platform)
            except KinesphereError as exc:
                if exc.code in ("invalid_eurdf", "malformed"):  # asking again gets the same
                    self._refuse("body", f"body of platform {platform} refused ({exc.message});"
                                 " its robots get joint states only")
                    continue
                log.warning("no body for platform %s (%s); robot_description and tf wait for "
                            "it, asking again in %g s", platform, exc.message,
                            self.options.body_retry_s)
                if not self._closed.wait(self.options.body_retry_s):
                    self._wanted.put(platform)
                continue
            except Exception as exc:  # a bug must not end the thread every platform waits on
                self._refuse("body", f"body of platform {platform} not bridged: {exc!r}")
                continue
            with self._lock:
                if self._closed.is_set():
                    return
                self._bodies[platform] = body
                for robot in self._robots.values():
                    if robot.platform == platform and robot.description is None:
                        self._describe(robot, body)

    def _fetch(self, platform: str) -> _Body:
        from kinesphere.eurdf import load_eurdf, plain_urdf  # yourdfpy: slow to import

        model = get_one(self.session, self.keys.body(platform), BodyModel,
                        timeout=self.options.body_timeout_s, every_replica=True)
        if len(model.eurdf.encode()) > self.options.max_urdf_bytes:
            raise KinesphereError("malformed", f"body of {platform} exceeds "
                                  f"{self.options.max_urdf_bytes} bytes")
        eurdf = load_eurdf(model.eurdf)  # validated: a malformed body is refused here
        urdf = plain_urdf(model.eurdf)
        return _Body(urdf, eurdf.root_link, JointFrames(eurdf), dict(model.neutral))

    def close(self) -> None:
        """Stop listening, undeclare every publisher and graph token."""
        undeclare(self._states, self._alive)
        with self._lock:
            self._closed.set()
            robots, self._robots = list(self._robots.values()), {}
        self._wanted.put(None)
        self._worker.join(timeout=self.options.body_timeout_s + 1.0)
        for robot in robots:
            robot.close()
        self.node.close()

