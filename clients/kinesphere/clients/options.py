"""How the operator's command streams run: the defaults every client command reads.

``gamepad``, ``send --for`` and ``play`` stream Commands; their command-line defaults and help
texts come from :class:`TeleopOptions`, so a changed default changes every command at once;
every command that sends names its sender with the one ``--sender`` of :func:`add_identity`.
Cheap to import: the CLI builds its parsers from it before any handler runs.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass


@dataclass(frozen=True)
class TeleopOptions:
    """``rate_hz`` Commands per second, each carrying ``ttl_ms`` (a robot that hears nothing
    newer for that long holds); ``deadman_required``: stream only while the deadman is held."""

    rate_hz: float = 30.0
    ttl_ms: int = 300
    deadman_required: bool = True


@dataclass(frozen=True)
class BridgeOptions:
    """``kinesphere ros2 bridge``: ROS ``domain`` and ``namespace``, ``node`` name, TF parent
    frame, ROS 2 ``distro`` of the keys it writes; how long a BodyModel query may take and the
    pause before asking again; bounds."""

    domain: int = 0
    namespace: str = "/"
    node: str = "kinesphere_bridge"
    odom_frame: str = "odom"
    distro: str = "jazzy"
    body_timeout_s: float = 2.0
    body_retry_s: float = 5.0
    max_robots: int = 256
    max_urdf_bytes: int = 1024 * 1024


JOY_LAYOUTS = ("controller", "joystick")


@dataclass(frozen=True)
class JoyOptions:
    """The gamepad's ``--input ros2:TOPIC``: ROS ``domain``; ``layout`` ``controller`` (the
    SDL GameController order of ``joy``'s game_controller_node) or ``joystick`` (joy_node's
    raw device order, read with the mapping's ``[joystick]`` numbers); after ``timeout_s``
    without a message the pad counts as unplugged (everything stops); ``distro`` the ROS 2
    distribution whose keys its graph token carries."""

    domain: int = 0
    layout: str = "controller"
    timeout_s: float = 0.5
    distro: str = "jazzy"


def add_identity(p: argparse.ArgumentParser) -> None:
    """``--sender``: who a command-line client is to the robots."""
    p.add_argument(
        "--sender",
        metavar="NAME",
        help="who you are to the robots (default $KINESPHERE_SENDER, else USER@HOST): they "
        "lease control to a sender and only its own release clears its e-stop, so your "
        "commands from several terminals count as one operator; behind the deploy's access "
        "control it must be the name in your certificate",
    )
