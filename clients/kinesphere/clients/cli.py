"""The operator's sub-commands: ``gamepad``, ``send``, ``play``, ``estop`` and ``lease``.

Only the parsers live here (registered by the ``kinesphere`` dispatcher through the
``kinesphere.commands`` entry point); the handlers are in their wings,
:mod:`kinesphere.clients.gamepad.handler` and :mod:`kinesphere.clients.orders.handlers` (the
commands that wait for acks), imported when a command runs: they bring Zenoh, mcap and the
streaming loop (~0.2 s), which ``kinesphere --help`` does not need.
"""

from __future__ import annotations

import argparse

from kinesphere.cliargs import (
    LaidOutHelpFormatter,
    Subcommands,
    add_ros_distro,
    add_ros_domain,
    add_score_options,
    add_zenoh_arguments,
    command,
)
from kinesphere.clients.options import (
    ANSWER,
    JOY_LAYOUTS,
    SEND,
    JoyOptions,
    OrderOptions,
    TeleopOptions,
    add_answers,
    add_duration,
    add_identity,
    add_lifetime,
    add_rate,
    add_target,
)

KEYS_HELP = """keys (keyboard fallback, the HUD window needs focus):
  arrows      right stick: the limb's horizontal direction (diagonals: two arrows)
  1 / 2 / 3   near / mid / far reach for the arrows and Q/E
  Q / E       low / high level (alone: Place Low / Place High)
  W A S D     left stick: drive the base      Z / C   turn the base left / right
  shift       turbo (full speed and turn rate)
  space       deadman (hold)          B       beyond: reach past far (hold, with 3)
  Tab / L     next limb / origin      T       next target (robot -> group -> all)
  Escape      E-STOP every robot      Enter   release the e-stops you latched
  K           take control (the lease) of the target from another operator
  F10         quit

gamepad (SDL layout, see clients/kinesphere/clients/gamepad/mappings/default.toml):
  right stick limb direction + reach   left stick   drive the base (proportional)
  LT / RT     low / high level         LB (hold)    deadman       RB (hold) beyond
  d-pad left/right: turn the base (hold)            L3 (hold)     turbo
  d-pad down/up: next/previous limb    X  next origin              Y  next target
  B           E-STOP every robot       Start        release the e-stops you latched
  Back        take control (the lease) of the target from another operator
"""


STREAM = TeleopOptions()
"""The defaults the streaming commands show and use."""


def _gamepad(args: argparse.Namespace) -> int:
    from kinesphere.clients.gamepad.handler import gamepad

    return gamepad(args)


def _send(args: argparse.Namespace) -> int:
    from kinesphere.clients.orders.handlers import send

    return send(args)


def _play(args: argparse.Namespace) -> int:
    from kinesphere.clients.orders.handlers import play

    return play(args)


def _estop(args: argparse.Namespace) -> int:
    from kinesphere.clients.orders.handlers import estop

    return estop(args)


def _lease(args: argparse.Namespace) -> int:
    from kinesphere.clients.orders.handlers import lease

    return lease(args)


def _sends(p: argparse.ArgumentParser, ttl: str = f"{STREAM.ttl_ms}",
           answers: tuple[OrderOptions, str] | None = None) -> None:
    """What every command that sends takes last: how long robots keep to its commands (and,
    when it waits for ``answers``, how long), who sends, the Zenoh session."""
    add_lifetime(p, ttl, wait=answers is not None)
    if answers is not None:
        add_answers(p, *answers)
    add_identity(p)
    add_zenoh_arguments(p)


def register(sub: Subcommands) -> None:
    fmt = LaidOutHelpFormatter
    g = command(
        sub, "gamepad", _gamepad,
        formatter_class=fmt,
        help="teleoperate robots with a gamepad (or the keyboard) and a HUD",
        description="Stream spatial commands from a gamepad: the right stick moves the "
        "selected limb (direction from its angle, size from its deflection, level from the "
        "triggers), the left stick drives the base, both at once. Commands go out at --rate "
        "while the deadman is held, each with --ttl-ms so robots stop if this client dies; "
        "letting go sends a final stop.",
        epilog=KEYS_HELP,
    )
    add_target(g, note="cycle with the target button")
    g.add_argument("--headless", action="store_true", help="no HUD window (needs a gamepad)")
    g.add_argument(
        "--mapping", metavar="FILE",
        help="TOML mapping laid over the defaults, "
        "clients/kinesphere/clients/gamepad/mappings/default.toml",
    )
    g.add_argument("--record", metavar="FILE", help="record the session (MCAP) to FILE")
    g.add_argument(
        "--replay",
        metavar="FILE",
        help="replay a recording instead of reading a device; exits when it ends",
    )
    add_rate(g, "while engaged")
    g.add_argument(
        "--no-deadman",
        action="store_true",
        help="stream whenever a stick or trigger is deflected (no deadman button)",
    )
    g.add_argument(
        "--input",
        default="pad",
        metavar="pad|ros2:TOPIC",
        help="where the hands come from: the local pad and keyboard (default), or "
        "sensor_msgs/Joy from a ROS 2 joy node over rmw_zenoh, e.g. ros2:/joy (ros2 extra)",
    )
    joy = JoyOptions()
    add_ros_domain(g, joy.domain, "the Joy topic")
    g.add_argument("--joy-layout", choices=JOY_LAYOUTS, default=joy.layout,
                   help="Joy axis/button order: game_controller_node's SDL order (default) or "
                   "joy_node's device order, read with the mapping's [joystick] numbers")
    g.add_argument("--joy-timeout", type=float, default=joy.timeout_s, metavar="S",
                   help=f"no Joy message for S seconds = pad unplugged (default {joy.timeout_s})")
    add_ros_distro(g, joy.distro, "the joy node's")
    add_duration(g)
    g.add_argument("--screenshot", metavar="PNG", help="save the HUD to PNG when quitting")
    g.add_argument(
        "--take",
        action="store_true",
        help="take control (the lease) of the target from another operator on every engage, "
        "instead of being refused while they hold it",
    )
    _sends(g)

    s = command(
        sub, "send", _send,
        formatter_class=fmt,
        help="send one command (L O D S ...) to a robot, a group or all",
        description="Send one Command with the given spatial parts, e.g.\n"
        "  kinesphere send baxter-1 limb_11 distal_11 left-high 3\n"
        "  kinesphere send all right_arm right_shoulder forward-low far --drive forward 0.3 "
        "--for 2\nLimbs and origins are labels or aliases; sizes are numbers or near/mid/far. "
        "With --for the command is repeated at --rate for that long (a drive needs that), then "
        "the deadman is let go.\nPrints one line per addressed robot (what it did, "
        "substitutions, refusals) and exits 1 unless every one accepted.",
    )
    add_target(s, positional=True)
    s.add_argument(
        "parts",
        nargs="*",
        metavar="L O D S",
        help="limb origin direction size, repeated for compound commands",
    )
    s.add_argument(
        "--drive",
        nargs=2,
        metavar=("DIR", "SPEED"),
        help="also drive the base along DIR (a middle horizontal) at SPEED 0..1",
    )
    s.add_argument(
        "--for",
        dest="hold",
        type=float,
        metavar="S",
        help="repeat the command for S seconds, then stop",
    )
    add_rate(s, "with --for")
    _sends(s, f"0: the pose is reached whatever happens next; {STREAM.ttl_ms} with --for",
           (SEND, "(the last command's final stage: reached, clamped, blocked...)"))

    p = command(
        sub, "play", _play,
        formatter_class=fmt,
        help="play a movement phrase (TOML) or a Labanotation score (JSON) on robots",
        description="Play a phrase: steps of spatial commands (and drives) with durations, "
        "streamed at --rate, then the deadman is let go. PHRASE is a file or a shipped phrase "
        "name: left_high, tour_guide, packbot_sweep, packbot_retreat. Prints one line per "
        "addressed robot and exits 1 unless every one accepted every step.\n\n"
        "Or play a Labanotation score (LabanotationSuite's JSON: a .json file, or the name of "
        "a score shipped in clients/scores/, e.g. big2): every gesture in it (or --gesture "
        "NAME), "
        "keyframe by keyframe at the score's times (--speed scales them), each body "
        "performing the head, upper arms and forearms it has (a one-armed body the right-arm "
        "columns; --check prints what each body performs and stops). After each keyframe the "
        "robots' reported joint states are notated back with LabanEditor's rule: one line "
        "per robot with the share of cells that come back as written; --report FILE.json "
        "writes every cell.",
    )
    p.add_argument("phrase", metavar="PHRASE|SCORE",
                   help="phrase file (TOML), score file (JSON) or a shipped name")
    add_target(p)
    add_rate(p, "while the phrase or score plays")
    add_score_options(p, "every gesture in turn")
    p.add_argument("--check", action="store_true",
                   help="a score: print what each body performs (and which cells its databank "
                   "cannot) and move nothing")
    p.add_argument("--report", metavar="FILE.json",
                   help="a score: write every keyframe's measured cells per robot to FILE.json")
    _sends(p, f"the phrase's ttl_ms, else {STREAM.ttl_ms}",
           (SEND, "after the phrase (a score: also the longest wait for a body's catalogue, "
            "and for the starting pose)"))

    e = command(
        sub, "estop", _estop,
        help="emergency-stop every robot (or --release the target's latch)",
        description="Put an e-stop Command on <prefix>/robot/*/command: every robot halts "
        "in place and latches until released; repeated until every live robot acknowledged "
        "it. Exits 1 when a robot did not, and loudly when no robot is there at all. "
        "--release clears the latch of --target (required: say whose).",
    )
    e.add_argument("--release", action="store_true", help="release instead of stopping")
    add_target(e, default=None, note="with --release: whose e-stop to release")
    _sends(e, answers=(ANSWER, "(estopped, released)"))

    ls = command(
        sub, "lease", _lease,
        formatter_class=fmt,
        help="acquire, take over or release control of a robot, a group or all",
        description="A robot obeys one operator (sender) at a time. 'acquire' asks for its "
        "control lease (refused while another operator holds it), 'take' takes it over (the "
        "robot logs it and tells the previous holder), 'release' gives it back. A lease lapses "
        "after 3 s without a command from its holder; --hold keeps it alive that long and "
        "then releases it. E-stop works whoever holds the lease.",
    )
    ls.add_argument("action", choices=("acquire", "take", "release"),
                    metavar="acquire|take|release", help="what to do with the lease")
    add_target(ls, positional=True)
    ls.add_argument("--hold", type=float, default=0.0, metavar="S",
                    help="keep the lease alive for S seconds (Ctrl-C ends it), then release")
    _sends(ls, answers=(ANSWER, "(leased, or refused naming the holder)"))
