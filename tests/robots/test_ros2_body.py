"""``--body ros2``: the agent drives a ros2_control robot over rmw_zenoh, no ROS installed.

The robot is ``test_ros2_support.StandInRobot``, which speaks only rmw_zenoh's wire format
(its own keys, rosbags, zenoh-ext attachments): it follows the trajectory stream and publishes
JointState. The agent, the databank and the gamepad client are the real ones on loopback
Zenoh; the operator's hands are posted pygame events, or a Joy message stream into the
``kinesphere gamepad --input ros2:/joy`` command.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import partial

import numpy as np
import pygame
import pytest
import zenoh
from rosbags.typesys.stores.ros2_jazzy import (
    std_msgs__msg__Float64MultiArray as Float64MultiArray,
)
from rosbags.typesys.stores.ros2_jazzy import (
    trajectory_msgs__msg__JointTrajectory as JointTrajectory,
)

from kinesphere import zconfig
from kinesphere.clients import targets as tg
from kinesphere.clients.gamepad import mapfile
from kinesphere.clients.gamepad.inputs import pad
from kinesphere.clients.gamepad.state import ControllerState
from kinesphere.clients.gamepad.teleop import Teleop, run
from kinesphere.clients.link import RobotLink
from kinesphere.clients.options import TeleopOptions
from kinesphere.errors import KinesphereError
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import Pose, RobotState, SpatialCommand
from kinesphere.robots.agent.bodies import make_body
from kinesphere.robots.agent.options import AgentOptions, Ros2BodyOptions
from support.agents import CommandSender, DatabankProcess, running_agent
from support.clients import Pad
from support.network import KEYS, Hub
from support.paths import ROOT
from support.ros2 import JAZZY, GraphWatch, RosPublisher, StandInRobot, dds
from support.wait import WAIT_S

PLATFORM = "baxter"
LIMB, ORIGIN = "limb_11", "distal_11"  # the right arm from the right shoulder
TOL = 0.02
"""rad: the stand-in counts as at a pose (its linear interpolation ends exactly there)."""


def neutral(platform: str = PLATFORM) -> dict[str, float]:
    p = load_platform(platform)
    return dict(zip(p.joint_names, p.neutral_vector().tolist(), strict=True))


def at(robot: StandInRobot, joints: dict[str, float], tol: float = TOL) -> bool:
    return all(abs(robot.q[j] - v) <= tol for j, v in joints.items())


def _moved_from(start: dict[str, float], joints: dict[str, float], by: float,
                robot: StandInRobot) -> bool:
    """Whether any of ``joints`` moved more than ``by`` from ``start``."""
    return max(abs(robot.q[j] - start[j]) for j in joints) > by


def _in_status(status: str, state: RobotState) -> bool:
    return state.status == status


@contextmanager
def ros_robot(endpoint: str, ns: str, platform: str = PLATFORM, interface: str = "trajectory",
              controller: str = "joint_trajectory_controller", order: list[str] | None = None
              ) -> Iterator[tuple[zenoh.Session, StandInRobot]]:
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        robot = StandInRobot(s, 0, ns, neutral(platform), interface, controller, order)
        try:
            yield s, robot
        finally:
            robot.close()


class Phases:
    """A teleop source that changes what the hands do when the robot gets somewhere."""

    def __init__(self, inp: pad.PygameInput,
                 phases: list[tuple[Callable[[], None], Callable[[], bool]]]) -> None:
        self.inp = inp
        self.phases = phases
        self.started = -1
        self.deadline = time.monotonic() + 2 * WAIT_S

    @property
    def finished(self) -> bool:
        if time.monotonic() > self.deadline:
            raise AssertionError(f"phase {self.started} never completed")
        return self.started >= len(self.phases)

    def poll(self) -> ControllerState:
        if self.started < 0 or self.phases[self.started][1]():
            self.started += 1
            if self.started < len(self.phases):
                self.phases[self.started][0]()
        return self.inp.poll()


@pytest.mark.realtime  # the released robot is at rest within 1.5 s, by the clock
def test_gamepad_moves_the_ros2_robot_to_an_ecl_pose_and_release_stops_it(
    hub: Hub, databank: DatabankProcess, pygame_up: None
) -> None:
    _, endpoint = hub
    rid, ns = "baxter-ros", "/baxter_ros"
    options = Ros2BodyOptions(namespace=ns)
    with ros_robot(endpoint, ns) as (ros, robot), \
            running_agent(endpoint, PLATFORM, rid, speed=1.0, control_rate=200.0, body="ros2",
                          ros2=options) as (agent, watch):
        assert watch.states[-1].q == pytest.approx(list(neutral().values()))
        js, jt = "sensor_msgs/msg/JointState", "trajectory_msgs/msg/JointTrajectory"
        sub = (f"/MS/%/%baxter_ros/kinesphere_baxter_ros/%baxter_ros%joint_states/"
               f"{dds(js)}/{JAZZY.hash_rihs01(js)}/::,10:,:,:,,")
        pub = (f"/MP/%/%baxter_ros/kinesphere_baxter_ros/%baxter_ros%joint_trajectory_"
               f"controller%joint_trajectory/{dds(jt)}/")
        graph = GraphWatch(ros, 0)  # the node's tokens arrive one by one: wait for both
        graph.wait(lambda ts: any(t.endswith(sub) for t in ts) and any(pub in t for t in ts),
                   "the agent's joint_states subscriber and joint_trajectory publisher")
        graph.close()

        p = Pad()
        target: dict[str, Pose] = {}
        inp = pad.PygameInput(mapfile.load())
        pygame.event.clear()
        with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
            link = RobotLink(s, KEYS)
            assert link.wait_subscribers([KEYS.command(rid)], WAIT_S) == []
            assert link.wait_for(lambda lk: rid in lk.states(), WAIT_S)
            op = Teleop(link, mapfile.load(), tg.robot(rid), TeleopOptions(30.0, 300))

            def reach_left() -> None:
                p.plug()
                p.deadman()
                p.right(-1.0, 0.0)  # right stick to the rim, left: left-middle, far

            def arrived() -> bool:
                if "a" not in target and op.intent.size >= 3.0:
                    part = SpatialCommand(op.selection.limb, op.selection.origin,
                                          op.intent.direction.slug, op.intent.size)
                    target["a"] = databank.query(PLATFORM, part)
                return "a" in target and at(robot, target["a"].joints)

            moved_from: dict[str, float] = {}

            def reach_up() -> None:
                p.deadman(False)
                p.right(0.0, 0.0)
                moved_from.update(robot.positions())

            def fresh_press() -> bool:
                p.deadman()
                p.right(1.0, -1.0)  # right-forward: towards another pose
                return True

            def under_way() -> bool:
                now = robot.positions()
                return max(abs(now[j] - moved_from[j]) for j in now) > 0.15

            released: list[float] = []

            def let_go() -> None:
                released.append(time.monotonic())
                p.deadman(False)

            script = Phases(inp, [(reach_left, arrived), (reach_up, lambda: True),
                                  (lambda: None, fresh_press), (lambda: None, under_way),
                                  (let_go, lambda: True)])
            assert (op.selection.limb, op.selection.origin) == (LIMB, ORIGIN)
            run(op, script, finished=lambda: script.finished)
            link.close()

        # the ECL pose was reached on the ROS robot, through the trajectory stream
        pose = target["a"]
        assert pose.limb == LIMB and pose.direction == "left-middle" and pose.size == 3.0
        assert robot.received, "no JointTrajectory reached the robot"
        # released mid-motion: the agent brakes, the robot comes to rest, short of the goal
        watch.wait(lambda st: st.status in ("holding", "stopped"), "the agent holding")
        rested_at = robot.wait_rest()
        assert rested_at - released[0] < 1.5, "the robot kept moving long after the release"
        assert under_way() and not at(robot, databank.query(PLATFORM, SpatialCommand(
            LIMB, ORIGIN, "right-forward-middle", 3.0)).joints), "it stopped short"
        lower = {lim.name: lim.lower for lim in load_platform(PLATFORM).eurdf.P}
        upper = {lim.name: lim.upper for lim in load_platform(PLATFORM).eurdf.P}
        for _, msg in robot.received:
            assert isinstance(msg, JointTrajectory), "the trajectory interface streams these"
            for n, v in zip(msg.joint_names, msg.points[-1].positions.tolist(), strict=True):
                assert lower[n] <= v <= upper[n], f"{n}={v} streamed outside its limits"
        assert agent.last_state is not None and agent.last_state.status != "error"


def test_joy_stream_drives_the_ros2_robot(hub: Hub,
                                          databank: DatabankProcess) -> None:
    """A ROS user's joystick: Joy messages at joy's autorepeat rate into ``kinesphere
    gamepad --input ros2:/joy`` (a real process), the robot a ROS 2 one."""
    _, endpoint = hub
    rid, ns = "baxter-joy", "/baxter_joy"
    part = SpatialCommand(LIMB, ORIGIN, "left-middle", 3.0)
    goal = databank.query(PLATFORM, part).joints
    buttons = {"lb": 0}
    axes = [0.0] * 6
    with ros_robot(endpoint, ns) as (ros, robot), \
            running_agent(endpoint, PLATFORM, rid, speed=1.0, control_rate=200.0, body="ros2",
                          ros2=Ros2BodyOptions(namespace=ns)) as (_, watch):
        joy = RosPublisher(ros, 0, "/joy", "sensor_msgs/msg/Joy", node="game_controller_node")
        stop = threading.Event()

        sent = threading.Condition()

        def joy_node() -> None:  # game_controller_node: a message every 50 ms (autorepeat)
            cls = JAZZY.types
            while not stop.wait(0.05):
                header = cls["std_msgs/msg/Header"](
                    stamp=cls["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="joy")
                b = np.zeros(15, dtype=np.int32)
                b[9] = buttons["lb"]  # LEFTSHOULDER: the deadman
                joy.put(cls["sensor_msgs/msg/Joy"](header=header,
                                                    axes=np.array(axes, dtype=np.float32),
                                                    buttons=b))
                with sent:
                    sent.notify_all()

        thread = threading.Thread(target=joy_node, daemon=True)
        thread.start()
        proc = subprocess.Popen(
            [sys.executable, "-m", "kinesphere.cli", "gamepad", "--headless", "--input",
             "ros2:/joy", "--target", rid, "--connect", endpoint, "--listen",
             zconfig.LOOPBACK_ANY_PORT],
            cwd=ROOT, env={**os.environ, "PYTHONUNBUFFERED": "1", "SDL_VIDEODRIVER": "dummy",
                           "SDL_AUDIODRIVER": "dummy"},
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )
        try:
            assert proc.stderr is not None
            assert "input: sensor_msgs/Joy on /joy" in proc.stderr.readline()
            graph = GraphWatch(ros, 0)
            graph.wait(lambda ts: any("/MS/" in t and "kinesphere_gamepad/%joy/" in t
                                      for t in ts), "the gamepad's Joy subscription")
            graph.close()
            with sent:  # a few messages with the deadman up: a held deadman needs a fresh press
                for _ in range(3):
                    assert sent.wait(WAIT_S)
            axes[2] = 1.0  # ROS: right stick full left
            buttons["lb"] = 1
            robot.wait(lambda r: at(r, goal), "reached the left-middle far pose")
            axes[2], axes[3] = -1.0, 1.0  # right-forward, then let go of the deadman midway
            moved_from = robot.positions()
            robot.wait(lambda r: max(abs(r.q[j] - moved_from[j]) for j in goal) > 0.15,
                       "started towards the next pose")
            buttons["lb"] = 0
            released = time.monotonic()
            watch.wait(lambda st: st.status in ("holding", "stopped"), "the agent holding")
            assert robot.wait_rest() - released < 1.5, "kept moving long after the release"
            assert not at(robot, goal)
        finally:
            stop.set()
            thread.join(timeout=5)
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=WAIT_S)
            joy.close()
        assert proc.returncode == 0, err


@pytest.mark.realtime  # after the TTL or an e-stop the robot rests within 1 s, by the clock
def test_ros2_body_faults_and_stops(hub: Hub, databank: DatabankProcess) -> None:
    """Wrong robot, no robot, targets past the limits, the forward-controller order, TTL and
    e-stop mid-motion, a robot that goes quiet and comes back."""
    _, endpoint = hub
    ns = "/baxter_f"
    order = list(reversed(load_platform(PLATFORM).joint_names))
    with ros_robot(endpoint, ns, interface="forward", controller="forward_position_controller",
                   order=order) as (ros, robot):
        for platform, opts, expect in (
            ("nao", Ros2BodyOptions(namespace=ns), "lack eURDF joints HeadYaw"),
            (PLATFORM, Ros2BodyOptions(namespace="/nobody", start_timeout_s=0.5),
             "no joint states on /nobody/joint_states"),
            (PLATFORM, Ros2BodyOptions(namespace=ns, interface="forward", joints=("nope",)),
             "--ros2-joints must name each joint of P once"),
        ):
            with pytest.raises(KinesphereError, match=expect):
                make_body("ros2", platform, 0.01, session=ros,
                          options=AgentOptions(body="ros2", ros2=opts), robot_id="x")

        options = Ros2BodyOptions(namespace=ns, interface="forward", joints=tuple(order))
        body = make_body("ros2", PLATFORM, 0.01, session=ros,
                         options=AgentOptions(body="ros2", ros2=options), robot_id="clamp")
        limits = body.limits
        n = len(robot.received)
        body.command(np.array([lim.upper + 5.0 for lim in limits]), (0.0, 0.0, 0.0))
        body.step()  # at 100 Hz with a 10 ms period: every step streams
        robot.wait(lambda r: len(r.received) > n, "got the clamped command")
        last = robot.received[-1][1]
        assert isinstance(last, Float64MultiArray), "the forward interface streams these"
        sent = dict(zip(order, last.data.tolist(), strict=True))
        assert sent == {lim.name: lim.upper for lim in limits}, "clamped to the hard limits"
        # halt streams where the robot is as the body last heard it: neutral, or the clamped
        # pose when the robot's joint state of it came in first (a race the load decides)
        n = len(robot.received)
        body.halt()
        robot.wait(lambda r: len(r.received) > n, "got the halt")
        halt = robot.received[-1][1]
        assert isinstance(halt, Float64MultiArray)
        held = dict(zip(order, halt.data.tolist(), strict=True))
        assert held in (neutral(), sent), "halted where the robot was, within its limits"
        robot.wait(lambda r: r.q == held, "holding where it was halted")
        body.close()

        with running_agent(endpoint, PLATFORM, "baxter-f", speed=1.0, control_rate=200.0,
                           body="ros2", ros2=options) as (_, watch):
            part = SpatialCommand(LIMB, ORIGIN, "forward-high", 2.0)
            goal = databank.query(PLATFORM, part).joints
            far = databank.query(PLATFORM, SpatialCommand(LIMB, ORIGIN, "right-low", 3.0)).joints
            with (zconfig.session(config=zconfig.loopback_config(endpoint)) as s,
                  CommandSender(s, "baxter-f") as operator):
                operator.send((LIMB, ORIGIN, "forward-high", 2.0))
                robot.wait(lambda r: at(r, goal), "reached forward-high mid via commands")
                for how in ({"ttl_ms": 150}, {"estop": True}):
                    start = robot.positions()
                    deadline = time.monotonic() + WAIT_S
                    while not robot.within(  # a client streaming every 50 ms ...
                            partial(_moved_from, start, far, 0.1), 0.05):
                        assert time.monotonic() < deadline, "never under way to right-low"
                        operator.send((LIMB, ORIGIN, "right-low", 3.0), ttl_ms=150)
                    if "estop" in how:  # ... then an e-stop, or silence past the TTL
                        operator.send(estop=True)
                    status = "estop" if "estop" in how else "holding"
                    watch.wait(partial(_in_status, status), status)
                    stopped = time.monotonic()
                    assert robot.wait_rest() - stopped < 1.0 and not at(robot, far), how
                    operator.send(release=True)
                    operator.send((LIMB, ORIGIN, "forward-high", 2.0))
                    robot.wait(lambda r: at(r, goal), "back at forward-high")
            robot.publishing.clear()  # the driver goes quiet
            err = watch.wait(lambda st: st.status == "error", "an error status")
            assert f"no joint states on {ns}/joint_states" in err.detail, err.detail
            robot.publishing.set()
            back = watch.wait(lambda st: st.status != "error", "recovery")
            assert back.status == "holding" and "working again" in back.detail
