"""``--input ros2:/joy``: sensor_msgs/Joy over rmw_zenoh as a pad behind the same mapping.

The ROS side is ``test_ros2_support.RosPublisher`` (rmw_zenoh's format written independently);
pygame runs with SDL's dummy drivers; Zenoh sessions are real, on loopback. The Joy input's
clock is the test's, so the silence timeout is exercised without sleeping.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterator
from contextlib import contextmanager

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import pygame  # noqa: E402
import pytest  # noqa: E402

from kinesphere import zconfig  # noqa: E402
from kinesphere.clients.gamepad import mapfile  # noqa: E402
from kinesphere.clients.gamepad.handler import _joy_topic  # noqa: E402
from kinesphere.clients.gamepad.inputs.pad import PygameInput, init_pygame  # noqa: E402
from kinesphere.clients.gamepad.inputs.ros2_joy import JoyInput  # noqa: E402
from kinesphere.clients.gamepad.state import Action  # noqa: E402
from kinesphere.clients.options import JoyOptions  # noqa: E402
from kinesphere.errors import KinesphereError  # noqa: E402
from support.clock import ManualClock
from support.ros2 import JAZZY, RosPublisher  # noqa: E402
from support.wait import WAIT_S  # noqa: E402

JOY = "sensor_msgs/msg/Joy"
# game_controller_node's order (SDL GameController): axes lx ly rx ry lt rt; buttons a b x y
# back guide start leftstick rightstick leftshoulder rightshoulder dpup dpdown dpleft dpright
A, B, LB, RB, DPDOWN = 0, 1, 9, 10, 12


def joy(axes: list[float], pressed: tuple[int, ...] = (), n_buttons: int = 15) -> object:
    cls = JAZZY.types
    header = cls["std_msgs/msg/Header"](stamp=cls["builtin_interfaces/msg/Time"](sec=0, nanosec=0),
                                         frame_id="joy")
    import numpy as np

    return cls[JOY](header=header, axes=np.array(axes, dtype=np.float32),
                    buttons=np.array([int(i in pressed) for i in range(n_buttons)],
                                     dtype=np.int32))


@contextmanager
def joy_rig(layout: str = "controller") -> Iterator[tuple[RosPublisher, JoyInput, ManualClock]]:
    init_pygame(headless=True)
    clock = ManualClock(100.0)
    try:
        with zconfig.loopback_pair() as (ros_side, ours):
            inp = JoyInput(ours, PygameInput(mapfile.load(None)), "/joy",
                           JoyOptions(domain=4, layout=layout, timeout_s=0.5), clock=clock)
            pub = RosPublisher(ros_side, 4, "/joy", JOY, node="game_controller_node")
            assert zconfig.wait_matching(pub.pub, WAIT_S)
            try:
                yield pub, inp, clock
            finally:
                pub.close()
                inp.close()
    finally:
        pygame.quit()


def send(pub: RosPublisher, inp: JoyInput, msg: object) -> None:
    count = inp.received
    pub.put(msg)
    assert inp.wait_received(count + 1, WAIT_S), "Joy message never arrived"


def test_game_controller_node_drives_the_default_mapping() -> None:
    with joy_rig() as (pub, inp, clock):
        # right stick full left (ROS: +1), right trigger pulled (ROS: -1), LB already held
        send(pub, inp, joy([0.0, 0.0, 1.0, 0.0, 0.0, -1.0], (LB,)))
        cs = inp.poll()
        assert cs.connected and cs.source == "controller"
        assert (cs.rx, cs.ry, cs.lt, cs.rt) == (-1.0, 0.0, 0.0, 1.0)  # SDL convention
        assert not cs.is_held(Action.DEADMAN), "held when the stream began: needs a fresh press"
        send(pub, inp, joy([0.0, 0.5, 1.0, 0.0, 0.0, -1.0]))
        send(pub, inp, joy([0.0, 0.5, 1.0, 0.0, 0.0, -1.0], (LB, DPDOWN)))
        cs = inp.poll()
        assert cs.is_held(Action.DEADMAN) and cs.ly == -0.5  # stick up is SDL -y
        assert cs.was_pressed(Action.LIMB_NEXT)
        send(pub, inp, joy([0.0] * 6, (LB, B)))
        cs = inp.poll()
        assert cs.was_pressed(Action.ESTOP) and not cs.was_pressed(Action.LIMB_NEXT)
        clock.now += 0.4
        assert inp.poll().connected  # within the timeout
        clock.now += 0.2
        cs = inp.poll()
        assert not cs.connected and not cs.is_held(Action.DEADMAN), "silence = unplugged"
        send(pub, inp, joy([0.0] * 6, (LB,)))  # back, deadman still down: not held yet
        cs = inp.poll()
        assert cs.connected and not cs.is_held(Action.DEADMAN)
        send(pub, inp, joy([0.0] * 6))
        send(pub, inp, joy([0.0] * 6, (LB,)))
        assert inp.poll().is_held(Action.DEADMAN)


def test_joy_node_device_order_uses_the_joystick_numbers() -> None:
    with joy_rig("joystick") as (pub, inp, _):
        # xpad through joy_node: triggers rest at +1 (ROS), deadman is button 4
        send(pub, inp, joy([0.0, 0.0, 1.0, 0.0, -1.0, -1.0, 0.0, 0.0], n_buttons=11))
        send(pub, inp, joy([0.0, 0.0, -1.0, 0.0, -1.0, 1.0, 0.0, 0.0], (4,), n_buttons=11))
        cs = inp.poll()
        assert cs.source == "joystick" and cs.is_held(Action.DEADMAN)
        assert cs.lt == 1.0 and cs.rt == 0.0 and cs.ry == 1.0  # right stick (axis 4) down


def test_bad_joy_messages_are_dropped() -> None:
    with joy_rig() as (pub, inp, _):
        pub.pub.put(b"\x00\x01\x00\x00garbage")  # not CDR, and no attachment
        pub.put(joy([math.nan, 0.0]))  # decodes, but the reader refuses it
        send(pub, inp, joy([0.0, 0.0, 0.25], n_buttons=200))  # 200 buttons: the first 64 read
        cs = inp.poll()
        assert cs.rx == -0.25 and inp.received == 1
        assert inp.subscription.rejected == 2  # one publisher: the bad two came first
        assert "non-finite" in inp.subscription.last_error


def test_input_option() -> None:
    assert _joy_topic("pad") is None
    assert _joy_topic("ros2:/joy") == "/joy"
    assert _joy_topic("ros2:") == "/joy"
    assert _joy_topic("ros2:teleop/joy") == "/teleop/joy"
    for bad in ("sdl", "ros2:/bad-topic"):
        with pytest.raises(KinesphereError):
            _joy_topic(bad)
