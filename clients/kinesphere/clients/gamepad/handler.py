"""The ``gamepad`` handler and the plumbing every operator command shares (the others, which
wait for acks, are in :mod:`kinesphere.clients.orders`).

Heavy imports (pygame, Zenoh) happen inside the handlers so ``kinesphere --help`` stays quick.
Every handler closes its Zenoh session before returning, and every command that moved a robot
ends by letting go, also on Ctrl-C and SIGTERM. Handlers return exit codes; user mistakes raise
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

# --- shared plumbing --------------------------------------------------------------------------


@contextmanager
def link_for(args: argparse.Namespace) -> Iterator[Any]:
    """A watching RobotLink as ``args.sender`` on a session made from the Zenoh options."""
    from kinesphere.clients.link import RobotLink
    from kinesphere.keyexpr import Keys
    from kinesphere.zconfig import session_from_args

    keys = Keys(args.prefix)
    with session_from_args(args) as session:
        link = RobotLink(session, keys, sender=args.sender)
        try:
            yield link
        finally:
            link.close()


def reachable(link: Any, target: Any, wait: float) -> list[str]:
    """The target's command keys, once a robot listens on each; else unavailable, with a hint
    when a robot id was given for what is a group, or is near a live robot's id."""
    from kinesphere.clients import targets
    from kinesphere.errors import did_you_mean

    keys: list[str] = target.keys(link.keys)
    missing = link.wait_subscribers(keys, wait)
    if missing:
        hint = ""
        if target.kind == "robot":
            as_group = targets.group(target.name)
            if not link.wait_subscribers(as_group.keys(link.keys), 0.5):
                hint = f"; did you mean --target {as_group.spelling}?"
            else:
                hint = did_you_mean(target.name, link.alive_robots())
        raise KinesphereError(
            "unavailable", f"no robot listens on {', '.join(missing)} (waited {wait:g} s){hint}"
        )
    return keys


@contextmanager
def signals(on_stop: Callable[[], None]) -> Iterator[None]:
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
        with link_for(args) as link, ExitStack() as stack:
            op = teleop.Teleop(link, mapping, target, options, take=args.take)
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
                with signals(stop):
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
