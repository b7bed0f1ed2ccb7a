"""Handlers of the operator commands (``gamepad``, ``send``, ``play``, ``estop``).

Heavy imports (pygame, Zenoh) happen inside the handlers so ``kinesphere --help`` stays quick.
Every handler closes its Zenoh session before returning, and every command that moved a robot
ends with a stop, also on Ctrl-C and SIGTERM. Handlers return exit codes; user mistakes raise
KinesphereError.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from types import FrameType
from typing import Any

from kinesphere.clients.options import TeleopOptions
from kinesphere.errors import KinesphereError

ESTOP_REPEATS = 3
ESTOP_SPACING_S = 0.1
"""``kinesphere estop`` sends at once, then again once a robot is matched, then once more: it
latches, so copies are harmless, and a robot whose subscription reached this fresh session a
moment later still gets one."""


# --- shared plumbing --------------------------------------------------------------------------


@contextmanager
def _link(args: argparse.Namespace, watch: bool = False) -> Iterator[Any]:
    from kinesphere.clients.link import RobotLink
    from kinesphere.keyexpr import Keys
    from kinesphere.zconfig import session_from_args

    keys = Keys(args.prefix)
    with session_from_args(args) as session:
        link = RobotLink(session, keys, watch=watch)
        try:
            yield link
        finally:
            link.close()


def _reachable(link: Any, target: Any, wait: float) -> list[str]:
    """The target's command keys, once a robot listens on each; else unavailable, with a hint
    when a robot id was given for what is a group."""
    from kinesphere.clients import targets

    keys: list[str] = target.keys(link.keys)
    missing = link.wait_subscribers(keys, wait)
    if missing:
        hint = ""
        if target.kind == "robot":
            as_group = targets.group(target.name)
            if not link.wait_subscribers(as_group.keys(link.keys), 0.5):
                hint = f"; did you mean --target {as_group.spelling}?"
        raise KinesphereError(
            "unavailable", f"no robot listens on {', '.join(missing)} (waited {wait:g} s){hint}"
        )
    return keys


@contextmanager
def _signals(on_stop: Callable[[], None]) -> Iterator[None]:
    """SIGTERM (and SIGINT) end the work through ``on_stop`` so the final stop still goes out."""

    from kinesphere.signals import handle_signals

    def handler(signum: int, frame: FrameType | None) -> None:
        on_stop()

    with handle_signals(handler, (signal.SIGTERM, signal.SIGINT)):
        yield


# --- handlers -----------------------------------------------------------------------------


def gamepad(args: argparse.Namespace) -> int:
    from kinesphere.clients import mapfile, record, targets, teleop

    mapping = mapfile.load(args.mapping)
    target = targets.parse_target(args.target)
    ttl = TeleopOptions.ttl_ms if args.ttl_ms is None else args.ttl_ms
    if args.rate <= 0 or ttl < 0:
        raise KinesphereError("malformed", "--rate must be > 0 and --ttl-ms >= 0")
    options = TeleopOptions(args.rate, ttl, not args.no_deadman)
    replay = record.Replay.from_file(args.replay) if args.replay else None
    joy_topic = _joy_topic(args.input)
    hud = None
    use_pygame = replay is None or not args.headless
    if use_pygame:
        from kinesphere.clients import input as pad

        pad.init_pygame(args.headless)
        if args.headless and replay is None and joy_topic is None and pad.controllers() == 0:
            print("no game controller found: waiting for one to be plugged in; nothing moves "
                  "until then (--headless has no keyboard)", file=sys.stderr)
    try:
        with _link(args, watch=True) as link, ExitStack() as stack:
            op = teleop.Teleop(link, mapping, target, options)
            source: teleop.Source = replay if replay is not None else pad.PygameInput(mapping)
            if joy_topic is not None and replay is None:
                source = joy = _joy_input(args, link.session, source, joy_topic)
                stack.callback(joy.close)
            if not args.headless:
                from kinesphere.clients.hud import Hud

                hud = Hud()  # raises KinesphereError without a display
            deadline = None if args.duration is None else time.monotonic() + args.duration

            def finished() -> bool:
                if replay is not None and replay.finished:
                    return True
                return deadline is not None and time.monotonic() >= deadline

            def draw(view: teleop.View) -> None:
                if hud is not None:
                    if replay is not None:  # no input reads the queue: watch for a close
                        import pygame

                        if pygame.event.get(pygame.QUIT):
                            op.quit = True
                        pygame.event.pump()
                    hud.draw(view)

            recorder = (
                record.Recorder(
                    args.record, target=target.name, rate_hz=args.rate, mapping=mapping.source
                )
                if args.record
                else None
            )

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


def _joy_topic(text: str) -> str | None:
    """The ROS topic of ``--input ros2:TOPIC``, None for ``pad``; anything else is malformed."""
    if text == "pad":
        return None
    if not text.startswith("ros2:"):
        raise KinesphereError("malformed", f"--input {text!r}: use pad or ros2:TOPIC")
    from kinesphere.clients.ros2joy import input_topic

    return input_topic(text)


def _joy_input(args: argparse.Namespace, session: Any, pad: Any, topic: str) -> Any:
    from kinesphere.clients.options import JoyOptions
    from kinesphere.clients.ros2joy import JoyInput

    options = JoyOptions(args.ros2_domain, args.joy_layout, args.joy_timeout)
    print(f"input: sensor_msgs/Joy on {topic} (ROS domain {options.domain}); nothing moves "
          "until it arrives", file=sys.stderr, flush=True)
    return JoyInput(session, pad, topic, options)


def _parse_parts(words: list[str]) -> list[Any]:
    from kinesphere.clients.phrases import parse_part

    if len(words) % 4:
        raise KinesphereError(
            "malformed", f"parts come in fours (LIMB ORIGIN DIRECTION SIZE), got {len(words)} words"
        )
    return [parse_part(" ".join(words[i : i + 4]), "send") for i in range(0, len(words), 4)]


def send(args: argparse.Namespace) -> int:
    from kinesphere.clients import targets
    from kinesphere.clients.link import Sequencer, new_sender
    from kinesphere.clients.phrases import make_drive

    parts = _parse_parts(args.parts)
    drive = make_drive(args.drive[0], args.drive[1], "--drive") if args.drive else None
    if not parts and drive is None:
        raise KinesphereError("malformed", "nothing to send: give L O D S parts and/or --drive")
    target = targets.parse_target(args.target)
    hold = args.hold
    ttl = args.ttl_ms if args.ttl_ms is not None else (TeleopOptions.ttl_ms if hold else 0)
    seq = Sequencer(new_sender("send"), ttl)
    stopping = False

    def stop() -> None:
        nonlocal stopping
        stopping = True

    with _link(args) as link:
        keys = _reachable(link, target, args.wait)
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


def play(args: argparse.Namespace) -> int:
    from kinesphere.clients import phrases, targets
    from kinesphere.clients.link import Sequencer, new_sender

    phrase = phrases.load_phrase(args.phrase)
    target = targets.parse_target(args.target)
    ttl = args.ttl_ms if args.ttl_ms is not None else (phrase.ttl_ms or TeleopOptions.ttl_ms)
    seq = Sequencer(new_sender("play"), ttl)
    stopping = False

    def stop() -> None:
        nonlocal stopping
        stopping = True

    def on_step(i: int, step: phrases.Step) -> None:
        note = f": {step.note}" if step.note else ""
        print(f"step {i + 1}/{len(phrase.steps)} ({step.duration:g} s){note}", file=sys.stderr)

    with _link(args) as link:
        keys = _reachable(link, target, args.wait)
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


def estop(args: argparse.Namespace) -> int:
    from kinesphere.clients import targets
    from kinesphere.clients.link import Sequencer, new_sender

    seq = Sequencer(new_sender("estop"), 0)
    with _link(args) as link:
        if args.release:
            if args.target is None:
                raise KinesphereError(
                    "malformed", "--release needs --target ID, group:NAME or all: say whose "
                    "e-stop to release")
            target = targets.parse_target(args.target)
            keys = _reachable(link, target, args.wait)
            link.put(keys, seq.release())
            print(f"released the e-stop of {target.label}", file=sys.stderr)
        else:
            link.estop_all(seq)  # at once: an e-stop never waits for discovery
            missing = link.wait_subscribers([link.keys.command("*")], args.wait)
            for _ in range(ESTOP_REPEATS - 1):  # robots discovered a moment later get a copy
                link.estop_all(seq)
                time.sleep(ESTOP_SPACING_S)
            note = " (no robot was listening)" if missing else ""
            print(f"E-STOP sent to every robot{note}", file=sys.stderr)
    return 0
