"""The ``gamepad`` handler: a pad (or ROS 2 Joy, or a recording), the HUD, the streaming loop.

pygame (the pad and the HUD) and the ROS 2 Joy input are imported only when this run uses
them: a ``--headless --replay`` needs neither. The handler closes its Zenoh session before
returning, and lets go of every robot it moved, also on Ctrl-C and SIGTERM. It returns an exit
code; user mistakes raise KinesphereError.
"""

from __future__ import annotations

import argparse
import sys
import time
from contextlib import ExitStack
from typing import TYPE_CHECKING

import zenoh

from kinesphere.clients import targets
from kinesphere.clients.gamepad import mapfile, teleop
from kinesphere.clients.gamepad.inputs import ticks
from kinesphere.clients.gamepad.readout import Readout
from kinesphere.clients.link import link_for, signals
from kinesphere.clients.options import JoyOptions, TeleopOptions
from kinesphere.errors import KinesphereError

if TYPE_CHECKING:
    from kinesphere.clients.gamepad.hud import Hud
    from kinesphere.clients.gamepad.inputs.pad import PygameInput
    from kinesphere.clients.gamepad.inputs.ros2_joy import JoyInput


def gamepad(args: argparse.Namespace) -> int:
    mapping = mapfile.load(args.mapping)
    target = targets.parse_target(args.target)
    ttl = TeleopOptions.ttl_ms if args.ttl_ms is None else args.ttl_ms
    if args.rate <= 0 or ttl < 0:
        raise KinesphereError("malformed", "--rate must be > 0 and --ttl-ms >= 0")
    options = TeleopOptions(args.rate, ttl, not args.no_deadman)
    replay = ticks.TickReplay.from_file(args.replay) if args.replay else None
    joy_topic = _joy_topic(args.input)
    hud: Hud | None = None
    use_pygame = replay is None or not args.headless
    if use_pygame:
        from kinesphere.clients.gamepad.inputs import pad

        pad.init_pygame(args.headless)
    if replay is not None:
        print(f"input: the recording {args.replay}", file=sys.stderr)
    elif joy_topic is None:
        _say_input(pad.found(), args.headless, mapping)
    try:
        with link_for(args, ros2=joy_topic is not None) as link, ExitStack() as stack:
            op = teleop.Teleop(link, mapping, target, options, take=args.take)
            source: teleop.Source
            if replay is not None:
                source = replay
            else:
                source = device = pad.PygameInput(mapping)
                if joy_topic is not None:
                    source = joy = _joy_input(args, link.session, device, joy_topic)
                    stack.callback(joy.close)
            if not args.headless:
                from kinesphere.clients.gamepad.hud import Hud

                hud = Hud()  # raises KinesphereError without a display
            deadline = None if args.duration is None else time.monotonic() + args.duration

            def finished() -> bool:
                if replay is not None and replay.finished:
                    return True
                return deadline is not None and time.monotonic() >= deadline

            def draw(view: Readout) -> None:
                if hud is not None:
                    if replay is not None:  # no input reads the queue: watch for a close
                        import pygame

                        if pygame.event.get(pygame.QUIT):
                            op.quit = True
                        pygame.event.pump()
                    hud.draw(view)

            recorder = (
                ticks.TickRecorder(
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


def _say_input(pads: list[str], headless: bool, mapping: mapfile.MapFile) -> None:
    """Which input this session reads, on stderr, before anything else happens."""
    keys = "" if headless else (f"; the keyboard works in the HUD window too (hold "
                                f"{mapping.press('deadman', 'keyboard')} as the deadman)")
    if pads:
        print(f"input: {', '.join(pads)}{keys}", file=sys.stderr)
    elif headless:
        print("input: no game controller found: waiting for one to be plugged in; nothing "
              "moves until then (--headless has no keyboard)", file=sys.stderr)
    else:
        print("input: no game controller found: the keyboard, in the HUD window (hold "
              f"{mapping.press('deadman', 'keyboard')} as the deadman; a pad plugged in later "
              "works at once)", file=sys.stderr)


def _joy_topic(text: str) -> str | None:
    """The ROS topic of ``--input ros2:TOPIC``, None for ``pad``; anything else is malformed."""
    if text == "pad":
        return None
    if not text.startswith("ros2:"):
        raise KinesphereError("malformed", f"--input {text!r}: use pad or ros2:TOPIC")
    from kinesphere.clients.gamepad.inputs.ros2_joy import input_topic

    return input_topic(text)


def _joy_input(
    args: argparse.Namespace, session: zenoh.Session, pad: PygameInput, topic: str
) -> JoyInput:
    from kinesphere.clients.gamepad.inputs.ros2_joy import JoyInput

    options = JoyOptions(args.ros2_domain, args.joy_layout, args.joy_timeout,
                         args.ros_distro)
    print(f"input: sensor_msgs/Joy on {topic} (ROS domain {options.domain}); nothing moves "
          "until it arrives", file=sys.stderr, flush=True)
    return JoyInput(session, pad, topic, options)
