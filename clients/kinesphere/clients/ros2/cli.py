"""``kinesphere ros2 ...``: kinesphere seen from ROS 2 over rmw_zenoh (no ROS installation).

Registered through the ``kinesphere.commands`` entry point of the clients distribution; the
handler imports Zenoh, so ``--help`` stays quick.
"""

from __future__ import annotations

import argparse
import sys
import threading
from types import FrameType

from kinesphere.cliargs import (
    LaidOutHelpFormatter,
    Subcommands,
    ZenohDefaults,
    add_ros_distro,
    add_ros_domain,
    add_zenoh_arguments,
    command,
    command_group,
)
from kinesphere.clients.options import BridgeOptions

BRIDGE_EPILOG = """topics, for robot ID (made a ROS name: baxter-1 -> baxter_1), relative to NS:
  ID/joint_states       sensor_msgs/msg/JointState   at the robot's state rate
  ID/robot_description  std_msgs/msg/String          the URDF, transient local (RViz)
  ID/odom               nav_msgs/msg/Odometry        the base pose in ODOM
  tf                    tf2_msgs/msg/TFMessage       ODOM -> ID/<root link>, moving joints
  tf_static             tf2_msgs/msg/TFMessage       fixed joints, transient local
Frames are the URDF's links prefixed ID/, as robot_state_publisher with frame_prefix ID/
makes them: rviz2 with Fixed Frame ODOM shows every robot from the bridge alone.
ROS 2 side: RMW_IMPLEMENTATION=rmw_zenoh_cpp, both sides connected to the same Zenoh router
(ros2 run rmw_zenoh_cpp rmw_zenohd); see docs/ros2.md."""


BRIDGE_ZENOH = ZenohDefaults(
    note="Point it at the router the ROS 2 nodes use: rmw_zenohd listens on 7447 by default."
)
"""The bridge joins the default endpoint and listens (ROS peers connect to it directly)."""


def register(sub: Subcommands) -> None:
    rsub = command_group(
        sub, "ros2",
        help="ROS 2 over rmw_zenoh: show the robots to ROS tools",
        description="Speak ROS 2's Zenoh middleware (rmw_zenoh_cpp, Jazzy) without a ROS "
        "installation. The gamepad takes a ROS joystick with --input ros2:/joy; the agent "
        "drives a ros2_control robot with --body ros2.",
        dest="ros2_command",
    )
    d = BridgeOptions()
    b = command(
        rsub, "bridge", bridge,
        formatter_class=LaidOutHelpFormatter,
        help="publish every live robot's joint states, URDF, frames and odometry to ROS 2",
        description="Run one ROS node that republishes every live kinesphere robot for ROS 2 "
        "tools (ros2 topic, RViz, Foxglove, ros2 bag) until SIGINT/SIGTERM.",
        epilog=BRIDGE_EPILOG,
    )
    add_ros_domain(b, d.domain, "the node", alias="--domain")
    b.add_argument("--namespace", default=d.namespace, metavar="NS",
                   help=f"ROS namespace of the node and its topics (default {d.namespace})")
    b.add_argument("--node", default=d.node, help=f"ROS node name (default {d.node})")
    b.add_argument("--odom-frame", default=d.odom_frame, metavar="ODOM",
                   help=f"TF parent frame of every robot's base (default {d.odom_frame})")
    add_ros_distro(b, d.distro, "the ROS nodes'",
                   note="the keys written follow it: humble's carry no type hash")
    add_zenoh_arguments(b, BRIDGE_ZENOH)


def bridge(args: argparse.Namespace) -> int:
    import dataclasses

    from kinesphere.clients.ros2.bridge import Bridge
    from kinesphere.keyexpr import Keys
    from kinesphere.signals import handle_signals
    from kinesphere.zconfig import session_from_args

    options = dataclasses.replace(BridgeOptions(), domain=args.ros2_domain,
                                  namespace=args.namespace, node=args.node,
                                  odom_frame=args.odom_frame, distro=args.ros_distro)
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    with session_from_args(args, ros2=True) as session, handle_signals(on_signal):
        br = Bridge(session, Keys(args.prefix), options)
        try:
            print(f"bridging kinesphere robots to ROS 2 domain {options.domain} as node "
                  f"{br.node.resolve(options.node)}; Ctrl-C to stop", file=sys.stderr, flush=True)
            while not stop.wait(0.5):
                pass
        finally:
            br.close()
        print(f"bridged {br.stats.states} states", file=sys.stderr)
    return 0
