"""How the operator's commands run: the defaults every client command reads, and the option
families they share.

``gamepad``, ``send --for`` and ``play`` stream Commands; their command-line defaults and help
texts come from :class:`TeleopOptions`, so a changed default changes every command at once;
``send``, ``play``, ``estop`` and ``lease`` wait for answers as :class:`OrderOptions` say.
Every command that sends names its sender with the one ``--sender`` of :func:`add_identity`,
whom it addresses with :func:`add_target`. Cheap to import: the CLI builds its parsers from it
before any handler runs.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

from kinesphere.cliargs import add_timeout, add_wait


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


@dataclass(frozen=True)
class OrderOptions:
    """``send``, ``play``, ``estop`` and ``lease``: wait up to ``wait_s`` for the addressed
    robots to be reachable, then up to ``timeout_s`` for their answers."""

    wait_s: float = 5.0
    timeout_s: float = 5.0


SEND = OrderOptions()
"""``send`` and ``play`` wait for the final stage of a motion."""
ANSWER = OrderOptions(timeout_s=2.0)
"""``estop`` and ``lease`` wait for an answer the robot gives at once."""


@dataclass(frozen=True)
class ViewOptions:
    """``kinesphere view``: the page on ``host``:``port``, scene updates at ``fps``."""

    host: str = "127.0.0.1"
    port: int = 8080
    fps: float = 30.0


REPLAYED = ("commands", "states", "all")
"""What ``kinesphere replay`` can put back."""


@dataclass(frozen=True)
class TrafficOptions:
    """``kinesphere record`` stops past ``max_mb`` MB; ``kinesphere replay`` puts back
    ``what`` (one of :data:`REPLAYED`) at ``speed`` times the recorded pace, silences
    shortened to ``max_gap_s``, once each recorded key has a subscriber or ``wait_s``
    passed."""

    max_mb: float = 1024.0
    what: str = REPLAYED[0]
    speed: float = 1.0
    max_gap_s: float = 10.0
    wait_s: float = 5.0


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


def add_target(p: argparse.ArgumentParser, *, positional: bool = False,
               default: str | None = "all", note: str = "") -> None:
    """Whom a command addresses: ``TARGET`` (``positional``) or ``--target``."""
    said = [f"default {default}"] if default is not None and not positional else []
    said += [note] if note else []
    text = "robot id, group:NAME (agents run with --group) or 'all'" + (
        f" ({'; '.join(said)})" if said else "")
    if positional:
        p.add_argument("target", metavar="TARGET", help=text)
    else:
        p.add_argument("--target", default=default, metavar="ID|group:NAME|all", help=text)


def add_rate(p: argparse.ArgumentParser, when: str) -> None:
    """``--rate HZ``: Commands per second ``when`` streaming."""
    p.add_argument("--rate", type=float, default=TeleopOptions.rate_hz, metavar="HZ",
                   help=f"commands per second {when} (default {TeleopOptions.rate_hz:g})")


def add_lifetime(p: argparse.ArgumentParser, default: str = f"{TeleopOptions.ttl_ms}",
                 wait: bool = True) -> None:
    """``--ttl-ms`` (how long robots keep to a command) and, unless ``wait`` is False,
    ``--wait`` (for the target robots to be reachable)."""
    p.add_argument("--ttl-ms", type=int, default=None, metavar="MS",
                   help=f"robots hold if no newer command arrives within MS (default {default})")
    if wait:
        add_wait(p, OrderOptions.wait_s, "the target robots to be reachable")


def add_answers(p: argparse.ArgumentParser, options: OrderOptions, what: str) -> None:
    """``--timeout S``: how long a command waits for every addressed robot's answer."""
    add_timeout(p, options.timeout_s, f"every addressed robot's answer {what}",
                then="a robot that does not answer makes the exit status 1")


def add_duration(p: argparse.ArgumentParser, verb: str = "quit") -> None:
    """``--duration S``: a command that runs until stopped ``verb``s after S seconds."""
    p.add_argument("--duration", type=float, metavar="S", help=f"{verb} after S seconds")


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
