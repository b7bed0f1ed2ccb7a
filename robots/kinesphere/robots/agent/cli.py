"""``kinesphere agent PLATFORM`` runs one robot, ``kinesphere agent --robot P:ID ...`` and
``kinesphere fleet FLEET.toml`` many in one process (``fleet.py``); each until SIGINT/SIGTERM,
then shuts down cleanly."""

from __future__ import annotations

import argparse
import logging
import os
import signal
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any

from kinesphere.cliargs import (
    AGENT,
    Subcommands,
    add_ros_distro,
    add_ros_domain,
    add_zenoh_arguments,
    command,
)
from kinesphere.errors import KinesphereError
from kinesphere.robots.agent.bodies import BODIES
from kinesphere.robots.agent.options import ROS2_INTERFACES, AgentOptions, Ros2BodyOptions
from kinesphere.robots.agent.workers import default_workers
from kinesphere.signals import handle_signals

log = logging.getLogger(__name__)

VIEWER_HZ = 60.0
DEFAULTS = AgentOptions()


def register(sub: Subcommands) -> None:
    p = command(sub, "agent", _agent)
    p.add_argument("platform", nargs="?",
                   help="platform name (see 'kinesphere platforms') or folder")
    p.add_argument("--id", dest="robot_id", help="robot id (default: the platform name)")
    p.add_argument("--robot", action="append", default=[], metavar="PLATFORM:ID",
                   help="run this robot too, on a fleet host (repeatable; instead of "
                   "PLATFORM; see 'kinesphere fleet')")
    d = DEFAULTS
    p.add_argument("--body", choices=sorted(BODIES), default=d.body,
                   help=f"what the agent drives (default {d.body}: the platform's MuJoCo model)")
    _loop_options(p)
    p.add_argument("--group", action="append", default=[], metavar="NAME",
                   help="also obey {prefix}/group/NAME/command (repeatable)")
    p.add_argument("--viewer", action="store_true", help="open a MuJoCo viewer window")
    r = d.ros2
    ros2 = p.add_argument_group(
        "--body ros2", description="Drive a ros2_control robot over rmw_zenoh (ROS 2's Zenoh "
        "middleware; no ROS installation): read NS/joint_states, stream the trajectory to its "
        "controller. Connect to the router its nodes use. See docs/ros2.md.")
    ros2.add_argument("--ros2-namespace", default=r.namespace, metavar="NS",
                      help=f"the robot's ROS namespace (default {r.namespace})")
    add_ros_domain(ros2, r.domain, "the robot's nodes")
    ros2.add_argument("--ros2-interface", choices=ROS2_INTERFACES, default=r.interface,
                      help="trajectory: JointTrajectory on CONTROLLER/joint_trajectory; "
                      "forward: Float64MultiArray on CONTROLLER/commands "
                      f"(default {r.interface})")
    ros2.add_argument("--ros2-controller", default=r.controller, metavar="CONTROLLER",
                      help="controller name (default joint_trajectory_controller, or "
                      "forward_position_controller with --ros2-interface forward)")
    ros2.add_argument("--ros2-joints", default="", metavar="J1,J2,...",
                      help="the forward controller's joint order (default: the eURDF's)")
    ros2.add_argument("--ros2-timeout", type=float, default=r.timeout_s, metavar="S",
                      help=f"no joint state for S seconds = error, hold (default {r.timeout_s:g})")
    ros2.add_argument("--ros2-cmd-vel", default=r.cmd_vel, metavar="TOPIC",
                      help=f"a mobile base's geometry_msgs/Twist topic (default {r.cmd_vel})")
    ros2.add_argument("--ros2-cmd-vel-stamped", action="store_true",
                      help="send geometry_msgs/TwistStamped (Jazzy's diff_drive_controller "
                      "requires it) instead of Twist")
    ros2.add_argument("--ros2-odom", default=r.odom, metavar="TOPIC",
                      help=f"a mobile base's nav_msgs/Odometry topic (default {r.odom})")
    add_ros_distro(ros2, r.distro, "the robot's")
    add_zenoh_arguments(p, AGENT)

    f = command(sub, "fleet", _fleet_file)
    f.add_argument("fleet", type=Path, metavar="FLEET.toml", help="the robots to run")
    _loop_options(f)
    add_zenoh_arguments(f, AGENT)


def _loop_options(p: argparse.ArgumentParser) -> None:
    """How the control loop runs (one robot or a fleet)."""
    d = DEFAULTS
    p.add_argument("--control-rate", type=float, default=d.control_rate, metavar="HZ",
                   help=f"control and physics loop rate in Hz (default {d.control_rate:g})")
    p.add_argument("--state-rate", type=float, default=d.state_rate, metavar="HZ",
                   help=f"RobotState rate in Hz (default {d.state_rate:g})")
    p.add_argument("--speed", type=float, default=d.speed,
                   help=f"robot seconds per wall second; 0 = as fast as possible "
                   f"(default {d.speed:g})")
    p.add_argument("--max-translation", type=float, default=d.max_translation_m, metavar="M",
                   help="metres of base translation one command may ask for; more is refused "
                   f"(default {d.max_translation_m:g})")
    p.add_argument("--strict-period", action="store_true",
                   help="step only on the fixed schedule: a command waits for the next tick "
                   "(default: the step due next runs as soon as a command arrives)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="with several robots: worker processes they are dealt to, each with "
                   "its own control loop and Zenoh session; one dying takes only its own "
                   f"robots (default: one per core, {default_workers()} here)")
    p.add_argument("--worker", help=argparse.SUPPRESS)  # K/N:DIGEST, from the parent
    p.add_argument("--physics-threads", type=int, default=None, metavar="N",
                   help="with several robots: threads stepping each worker's physics besides "
                   "its loop's own (default: one per further core a worker has, at most 3)")


def _viewer(body: Any) -> Any:
    """A passive MuJoCo viewer, or None (with a warning) where no display or model exists."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        log.warning("--viewer: no display (DISPLAY/WAYLAND_DISPLAY unset); running headless")
        return None
    if not (hasattr(body, "model") and hasattr(body, "data")):
        log.warning("--viewer: the %s body has no MuJoCo model to show", type(body).__name__)
        return None
    try:
        import mujoco.viewer

        return mujoco.viewer.launch_passive(body.model, body.data)
    except Exception as exc:  # GL or windowing failures must not kill the robot
        log.warning("--viewer: cannot open a window (%s); running headless", exc)
        return None


@contextmanager
def _until_signal() -> Iterator[threading.Event]:
    """An event set by SIGINT or SIGTERM (handlers restored afterwards)."""
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        log.info("signal %d: shutting down", signum)
        stop.set()

    with handle_signals(on_signal, (signal.SIGINT, signal.SIGTERM)):
        yield stop


def _say_if_alone(session: Any, who: str) -> None:
    """A robot that reached no router runs, but nobody can command it: say so at once, with
    the command that starts one (it joins by itself when one comes)."""
    from kinesphere.zconfig import alone

    why = alone(session)
    if why:
        log.warning("%s: %s; nobody can command it until then (it joins by itself when the "
                    "router is there)", who, why)


def _agent(args: argparse.Namespace) -> int:
    """run a robot (simulated, or a ROS 2 one) that follows spatial commands

    Run PLATFORM's body (its MuJoCo model, or with --body ros2 a ros2_control robot) in real time:
    it subscribes to {prefix}/robot/ID/command, resolves commands through the databank, moves along
    jerk-limited Ruckig trajectories and publishes {prefix}/robot/ID/state.
    """
    if args.robot:
        return _agent_robots(args)
    if args.platform is None:
        raise KinesphereError("malformed", "give a PLATFORM, or robots with --robot "
                              "PLATFORM:ID")
    extra = [flag for flag, given in (("--workers", args.workers is not None),
                                      ("--worker", args.worker is not None),
                                      ("--physics-threads", args.physics_threads is not None))
             if given]
    if extra:
        raise KinesphereError("malformed", f"{', '.join(extra)}: for several robots (--robot "
                              "PLATFORM:ID ..., or a fleet file), not one PLATFORM")
    from kinesphere.platforms.platform import platform_spelling
    from kinesphere.robots.agent.runtime import Agent
    from kinesphere.zconfig import close_session, session_from_args

    robot_id = args.robot_id or platform_spelling(Path(args.platform).name)  # PackBot: packbot
    ros2 = Ros2BodyOptions(
        namespace=args.ros2_namespace, domain=args.ros2_domain, interface=args.ros2_interface,
        controller=args.ros2_controller, timeout_s=args.ros2_timeout,
        joints=tuple(j.strip() for j in args.ros2_joints.split(",") if j.strip()),
        cmd_vel=args.ros2_cmd_vel, cmd_vel_stamped=args.ros2_cmd_vel_stamped,
        odom=args.ros2_odom, distro=args.ros_distro,
    )
    options = AgentOptions(control_rate=args.control_rate, state_rate=args.state_rate,
                           speed=args.speed, prefix=args.prefix, groups=tuple(args.group),
                           body=args.body, ros2=ros2, max_translation_m=args.max_translation,
                           strict_period=args.strict_period)
    with _until_signal() as stop:
        session = session_from_args(args, ros2=args.body == "ros2")
        agent: Agent | None = None
        viewer = None
        try:
            agent = Agent(args.platform, robot_id, session, options)
            agent.declare()
            _say_if_alone(session, f"robot {robot_id}")
            on_tick = None
            if args.viewer:
                viewer = _viewer(agent.controller.body)
            if viewer is not None:
                every = max(1, round(args.control_rate / VIEWER_HZ))
                v = viewer
                a = agent

                def on_tick() -> None:
                    if a.controller.steps % every == 0:
                        if not v.is_running():
                            stop.set()
                        v.sync()

            agent.run(stop, on_tick)
        finally:
            if viewer is not None:
                viewer.close()
            if agent is not None:
                agent.close()
            close_session(session)
    return 0


def _agent_robots(args: argparse.Namespace) -> int:
    """``kinesphere agent --robot P:ID ...``: a fleet host from the command line."""
    from kinesphere.robots.agent.fleet import RobotSpec, parse_robot

    extra = [flag for flag, given in (("PLATFORM", args.platform is not None),
                                      ("--id", args.robot_id is not None),
                                      ("--viewer", args.viewer)) if given]
    if extra:
        raise KinesphereError("malformed", f"--robot runs a fleet: {', '.join(extra)} "
                              "cannot be combined with it")
    groups = tuple(args.group)
    robots = [RobotSpec(r.platform, r.robot_id, groups) for r in map(parse_robot, args.robot)]
    return _run_fleet(args, robots, args.body)


def _fleet_file(args: argparse.Namespace) -> int:
    """run many simulated robots in one process (a fleet host)

    Run every robot of FLEET.toml on this host: the robots are dealt to --workers processes (one per
    core by default), each stepping its share of MuJoCo bodies in one control loop on its own Zenoh
    session; each robot keeps its own keys, liveliness token, state stream, acks, lease, watchdog
    and e-stop latch, and a worker that dies takes only its own robots. SIGTERM or SIGINT stops them
    all. FLEET.toml: [robots.ID] tables with platform = NAME and optional groups = [...], and an
    optional prefix.
    """
    from kinesphere.robots.agent.fleet import load_fleet_file

    robots, prefix = load_fleet_file(args.fleet)
    if prefix is not None and args.prefix != DEFAULTS.prefix and args.prefix != prefix:
        raise KinesphereError("malformed", f"--prefix {args.prefix!r} but {args.fleet} says "
                              f"prefix = {prefix!r}")
    if prefix is not None:
        args.prefix = prefix
    return _run_fleet(args, robots, DEFAULTS.body)


def _run_fleet(args: argparse.Namespace, robots: Sequence[Any], body: str) -> int:
    """The fleet host: its workers (``workers.py``), or, with one worker (or as one), the
    robots in this process."""
    from kinesphere.robots.agent.fleet import FleetHost, check_fleet
    from kinesphere.robots.agent.stepper import default_helpers
    from kinesphere.robots.agent.workers import check_listen, deal, run_workers, share
    from kinesphere.zconfig import close_session, session_from_args

    check_fleet(robots)
    if args.workers is not None and args.workers < 1:
        raise KinesphereError("malformed", f"--workers {args.workers}: give at least 1")
    options = AgentOptions(control_rate=args.control_rate, state_rate=args.state_rate,
                           speed=args.speed, prefix=args.prefix, body=body,
                           max_translation_m=args.max_translation,
                           strict_period=args.strict_period)
    if args.worker is not None:
        k, workers, robots = share(robots, args.worker)
        log.info("worker %d/%d of a fleet host: %s", k, workers,
                 ", ".join(r.robot_id for r in robots))
    else:
        workers = len(deal(robots, default_workers() if args.workers is None
                                   else args.workers))
        if workers > 1:
            check_listen(args.listen, workers)
            with _until_signal() as stop:
                return run_workers(args.command_line, robots, workers, stop)
    helpers = (default_helpers(workers) if args.physics_threads is None
               else args.physics_threads)
    with _until_signal() as stop:
        session = session_from_args(args)
        fleet: FleetHost | None = None
        try:
            fleet = FleetHost(robots, session, options, helpers=helpers)
            fleet.declare()
            _say_if_alone(session, f"fleet host ({len(robots)} robots)")
            fleet.run(stop)
        finally:
            if fleet is not None:
                fleet.close()
            close_session(session)
    return 0
