"""Operator commands: ``gamepad``, ``send``, ``play`` and ``estop``.

Heavy imports (pygame, Zenoh) happen inside the handlers so ``kinesphere --help`` stays quick.
Every handler closes its Zenoh session before returning, and every command that moved a robot
ends with a stop, also on Ctrl-C and SIGTERM.
"""

from __future__ import annotations

import argparse
import dataclasses
import signal
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import DEFAULT_PREFIX

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
ESTOP_REPEATS = 3
ESTOP_SPACING_S = 0.1
"""A one-shot e-stop is repeated: it latches, so copies are harmless, and a robot whose
subscription reached this fresh session a moment after the first match still gets one."""
KEYS_HELP = """keys (keyboard fallback, the HUD window needs focus):
  arrows      right stick: the limb's horizontal direction (diagonals: two arrows)
  1 / 2 / 3   near / mid / far reach for the arrows and Q/E
  Q / E       low / high level (alone: Place Low / Place High)
  W A S D     left stick: drive the base (hold shift for full speed)
  space       deadman (hold)          B       beyond: reach past far (hold, with 3)
  Tab / L     next limb / origin      T       next target (robot -> group -> all)
  Escape      E-STOP every robot      Enter   release the e-stop of the target
  F10         quit

gamepad (SDL layout, see clients/mappings/default.toml):
  right stick limb direction + reach   left stick   drive the base
  LT / RT     low / high level         LB (hold)    deadman       RB (hold) beyond
  d-pad       left/right: limb, up/down: origin     Y  next target
  B           E-STOP every robot       Start        release the e-stop
"""


def _zenoh(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("zenoh")
    g.add_argument(
        "--connect",
        action="append",
        metavar="EP",
        help=f"endpoint to join (repeatable; default {DEFAULT_ENDPOINT} unless "
        "--listen or --zenoh-config is given)",
    )
    g.add_argument(
        "--listen",
        action="append",
        metavar="EP",
        help="endpoint to listen on, e.g. tcp/0.0.0.0:7448 (repeatable)",
    )
    g.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help="Zenoh JSON5 config file; the options above override it",
    )
    g.add_argument(
        "--mode", choices=("peer", "client"), default=None, help="Zenoh session mode (default peer)"
    )
    g.add_argument(
        "--prefix",
        default=DEFAULT_PREFIX,
        help=f"key prefix of the deployment (default {DEFAULT_PREFIX})",
    )


def _targeting(p: argparse.ArgumentParser, ttl_default: str = "300") -> None:
    p.add_argument(
        "--groups",
        metavar="FILE",
        help="TOML file with [groups] name = [robot ids] (adds to the mapping's)",
    )
    p.add_argument(
        "--ttl-ms",
        type=int,
        default=None,
        metavar="MS",
        help=f"robots hold if no newer command arrives within MS (default {ttl_default})",
    )
    p.add_argument(
        "--wait",
        type=float,
        default=5.0,
        metavar="S",
        help="wait up to S seconds for the target robots to be reachable (default 5)",
    )


def register(sub: Any) -> None:
    fmt = argparse.RawDescriptionHelpFormatter
    g = sub.add_parser(
        "gamepad",
        formatter_class=fmt,
        help="teleoperate robots with a gamepad (or the keyboard) and a HUD",
        description="Stream spatial commands from a gamepad: the right stick moves the "
        "selected limb (direction from its angle, size from its deflection, level from the "
        "triggers), the left stick drives the base, both at once. Commands go out at --rate "
        "while the deadman is held, each with --ttl-ms so robots stop if this client dies; "
        "letting go sends a final stop.",
        epilog=KEYS_HELP,
    )
    g.add_argument(
        "--target",
        default="all",
        metavar="ID|GROUP|all",
        help="robot id, group name or 'all' (default all; cycle with the target button)",
    )
    g.add_argument("--headless", action="store_true", help="no HUD window (needs a gamepad)")
    g.add_argument(
        "--mapping", metavar="FILE", help="TOML mapping laid over clients/mappings/default.toml"
    )
    g.add_argument("--record", metavar="FILE", help="record the session (JSON lines) to FILE")
    g.add_argument(
        "--replay",
        metavar="FILE",
        help="replay a recording instead of reading a device; exits when it ends",
    )
    g.add_argument(
        "--rate",
        type=float,
        default=30.0,
        metavar="HZ",
        help="command rate while engaged (default 30)",
    )
    g.add_argument(
        "--no-deadman",
        action="store_true",
        help="stream whenever a stick or trigger is deflected (no deadman button)",
    )
    g.add_argument("--duration", type=float, metavar="S", help="quit after S seconds")
    g.add_argument("--screenshot", metavar="PNG", help="save the HUD to PNG when quitting")
    _targeting(g)
    _zenoh(g)
    g.set_defaults(func=_gamepad)

    s = sub.add_parser(
        "send",
        formatter_class=fmt,
        help="send one command (L O D S ...) to a robot, a group or all",
        description="Send one Command with the given spatial parts, e.g.\n"
        "  kinesphere send baxter-1 limb_11 distal_11 left-high 3\n"
        "  kinesphere send all right_arm right_shoulder forward-low far --drive forward 0.3 "
        "--for 2\nLimbs and origins are labels or aliases; sizes are numbers or near/mid/far. "
        "With --for the command is repeated at --rate for that long (a drive needs that), then "
        "a stop follows.",
    )
    s.add_argument("target", help="robot id, group name or 'all'")
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
    s.add_argument(
        "--rate", type=float, default=30.0, metavar="HZ", help="repeat rate with --for (default 30)"
    )
    s.add_argument("--mapping", metavar="FILE", help="mapping file whose [groups] to use")
    _targeting(s, "0: the pose is reached whatever happens next; 300 with --for")
    _zenoh(s)
    s.set_defaults(func=_send)

    p = sub.add_parser(
        "play",
        formatter_class=fmt,
        help="play a movement phrase (TOML) on a robot, a group or all",
        description="Play a phrase: steps of spatial commands (and drives) with durations, "
        "streamed at --rate, then a stop. PHRASE is a file or a shipped phrase name: "
        "left_high, tour_guide, packbot_sweep, packbot_retreat.",
    )
    p.add_argument("phrase", metavar="PHRASE", help="phrase file (TOML) or shipped name")
    p.add_argument("--target", default="all", help="robot id, group name or 'all' (default)")
    p.add_argument("--rate", type=float, default=30.0, metavar="HZ", help="default 30")
    p.add_argument("--mapping", metavar="FILE", help="mapping file whose [groups] to use")
    _targeting(p, "the phrase's ttl_ms, else 300")
    _zenoh(p)
    p.set_defaults(func=_play)

    e = sub.add_parser(
        "estop",
        help="emergency-stop every robot (or --release the target's latch)",
        description="Put an e-stop Command on <prefix>/robot/*/command: every robot halts "
        "in place and latches until released. --release clears the latch of --target.",
    )
    e.add_argument("--release", action="store_true", help="release instead of stopping")
    e.add_argument("--target", default="all", help="robots to release (default all)")
    e.add_argument("--mapping", metavar="FILE", help="mapping file whose [groups] to use")
    _targeting(e)
    _zenoh(e)
    e.set_defaults(func=_estop)


# --- shared plumbing --------------------------------------------------------------------------


@contextmanager
def _session(args: argparse.Namespace) -> Iterator[Any]:
    from kinesphere import zconfig

    connect = args.connect
    if connect is None and args.listen is None and args.zenoh_config is None:
        connect = [DEFAULT_ENDPOINT]
    with zconfig.session(args.mode, args.listen, connect, args.zenoh_config) as s:
        yield s


@contextmanager
def _link(args: argparse.Namespace, watch: bool = False) -> Iterator[Any]:
    from kinesphere.clients.link import RobotLink

    from kinesphere.keyexpr import Keys

    keys = Keys(args.prefix)
    with _session(args) as session:
        link = RobotLink(session, keys, watch=watch)
        try:
            yield link
        finally:
            link.close()


def _groups(args: argparse.Namespace) -> dict[str, tuple[str, ...]]:
    from kinesphere.clients import mapfile

    groups = dict(mapfile.load(getattr(args, "mapping", None)).groups)
    if args.groups:
        groups.update(mapfile.load_groups(args.groups))
    return groups


def _reachable(link: Any, keys: list[str], wait: float) -> None:
    missing = link.wait_subscribers(keys, wait)
    if missing:
        raise KinesphereError(
            "unavailable", f"no robot listens on {', '.join(missing)} (waited {wait:g} s)"
        )


@contextmanager
def _signals(on_stop: Callable[[], None]) -> Iterator[None]:
    """SIGTERM (and SIGINT) end the work through ``on_stop`` so the final stop still goes out."""

    def handler(signum: int, frame: FrameType | None) -> None:
        on_stop()

    previous = {s: signal.signal(s, handler) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


# --- handlers -----------------------------------------------------------------------------


def _gamepad(args: argparse.Namespace) -> int:
    from kinesphere.clients import mapfile, record, targets, teleop

    mapping = mapfile.load(args.mapping)
    groups = _groups(args)
    mapping = dataclasses.replace(mapping, groups=groups)
    target = targets.parse_target(args.target, groups)
    ttl = 300 if args.ttl_ms is None else args.ttl_ms
    if args.rate <= 0 or ttl < 0:
        raise KinesphereError("malformed", "--rate must be > 0 and --ttl-ms >= 0")
    options = teleop.TeleopOptions(args.rate, ttl, not args.no_deadman)
    replay = record.Replay.from_file(args.replay) if args.replay else None
    hud = None
    use_pygame = replay is None or not args.headless
    if use_pygame:
        from kinesphere.clients import input as pad

        pad.init_pygame(args.headless)
    try:
        with _link(args, watch=True) as link:
            op = teleop.Teleop(link, mapping, target, options)
            source: teleop.Source = replay if replay is not None else pad.PygameInput(mapping)
            if not args.headless:
                from kinesphere.clients.hud import Hud

                hud = Hud()
            deadline = None if args.duration is None else time.monotonic() + args.duration

            def finished() -> bool:
                if replay is not None and replay.finished:
                    return True
                return deadline is not None and time.monotonic() >= deadline

            def draw(view: teleop.View) -> None:
                if hud is not None:
                    if replay is not None:
                        import pygame

                        pygame.event.pump()  # keep the window responsive
                    hud.draw(view)

            recorder = record.Recorder(args.record, target=target.name) if args.record else None

            def stop() -> None:
                op.quit = True

            try:
                with _signals(stop):
                    teleop.run(op, source, draw=draw, record=recorder, finished=finished)
            finally:
                if recorder is not None:
                    recorder.close()
                if hud is not None and args.screenshot:
                    hud.screenshot(args.screenshot)
    finally:
        if use_pygame:
            import pygame

            pygame.quit()
    return 0


def _parse_parts(words: list[str]) -> list[Any]:
    from kinesphere.clients.phrases import parse_part

    if len(words) % 4:
        raise KinesphereError(
            "malformed", f"parts come in fours (LIMB ORIGIN DIRECTION SIZE), got {len(words)} words"
        )
    return [parse_part(" ".join(words[i : i + 4]), "send") for i in range(0, len(words), 4)]


def _send(args: argparse.Namespace) -> int:
    from kinesphere.clients import targets
    from kinesphere.clients.link import Sequencer, new_sender
    from kinesphere.clients.phrases import make_drive

    parts = _parse_parts(args.parts)
    drive = make_drive(args.drive[0], args.drive[1], "--drive") if args.drive else None
    if not parts and drive is None:
        raise KinesphereError("malformed", "nothing to send: give L O D S parts and/or --drive")
    target = targets.parse_target(args.target, _groups(args))
    hold = args.hold
    ttl = args.ttl_ms if args.ttl_ms is not None else (300 if hold else 0)
    seq = Sequencer(new_sender("send"), ttl)
    stopping = False

    def stop() -> None:
        nonlocal stopping
        stopping = True

    with _link(args) as link:
        keys = target.keys(link.keys)
        _reachable(link, keys, args.wait)
        with _signals(stop):
            link.put(keys, seq.command(parts, drive))
            if hold:
                end = time.monotonic() + hold
                while time.monotonic() < end and not stopping:
                    time.sleep(min(1.0 / args.rate, max(0.0, end - time.monotonic())))
                    link.put(keys, seq.command(parts, drive))
                link.put(keys, seq.stop())
    print(f"sent {seq.seq} command(s) to {target.label}", file=sys.stderr)
    return 0


def _play(args: argparse.Namespace) -> int:
    from kinesphere.clients import phrases, targets
    from kinesphere.clients.link import Sequencer, new_sender

    phrase = phrases.load_phrase(args.phrase)
    target = targets.parse_target(args.target, _groups(args))
    ttl = args.ttl_ms if args.ttl_ms is not None else (phrase.ttl_ms or 300)
    seq = Sequencer(new_sender("play"), ttl)
    stopping = False

    def stop() -> None:
        nonlocal stopping
        stopping = True

    def on_step(i: int, step: phrases.Step) -> None:
        note = f": {step.note}" if step.note else ""
        print(f"step {i + 1}/{len(phrase.steps)} ({step.duration:g} s){note}", file=sys.stderr)

    with _link(args) as link:
        keys = target.keys(link.keys)
        _reachable(link, keys, args.wait)
        print(f"playing {phrase.name} ({phrase.duration:g} s) on {target.label}", file=sys.stderr)
        with _signals(stop):
            phrases.play(
                link,
                phrase,
                keys,
                seq,
                rate_hz=args.rate,
                on_step=on_step,
                should_stop=lambda: stopping,
            )
    return 130 if stopping else 0


def _estop(args: argparse.Namespace) -> int:
    from kinesphere.clients import targets
    from kinesphere.clients.link import Sequencer, new_sender

    seq = Sequencer(new_sender("estop"), 0)
    with _link(args) as link:
        if args.release:
            target = targets.parse_target(args.target, _groups(args))
            keys = target.keys(link.keys)
            _reachable(link, keys, args.wait)
            link.put(keys, seq.release())
            print(f"released the e-stop of {target.label}", file=sys.stderr)
        else:
            keys = [link.keys.command("*")]
            missing = link.wait_subscribers(keys, args.wait)  # send even if nobody listens yet
            for i in range(ESTOP_REPEATS):  # robots still being discovered get a later copy
                if i:
                    time.sleep(ESTOP_SPACING_S)
                link.estop_all(seq)
            note = " (no robot was listening)" if missing else ""
            print(f"E-STOP sent to every robot{note}", file=sys.stderr)
    return 0
