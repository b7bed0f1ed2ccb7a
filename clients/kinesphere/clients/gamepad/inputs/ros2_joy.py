"""``sensor_msgs/msg/Joy`` from ROS 2 as one more pad behind the same mapping.

A ROS user's joystick setup (``ros2 run joy game_controller_node``) publishes Joy messages over
rmw_zenoh; :class:`JoyInput` subscribes to them and replays each one into the gamepad's
:class:`~kinesphere.clients.gamepad.inputs.pad.PygameInput` as the SDL events a locally
plugged pad would have produced, so the mapping file, the deadman, presses and hot-plug rules
are exactly those of a real pad. game_controller_node reports axes in SDL's GameController order
with ROS signs (stick up and left positive, a pulled trigger -1), so each value goes in negated:
SDL's convention. With ``layout="joystick"`` (joy_node's device order) they go in as raw
joystick events, read with the mapping's ``[joystick]`` numbers.

Safety: Joy messages repeat at game_controller_node's autorepeat rate (20 Hz by default) even
when nothing changes; when none arrives for ``timeout_s`` the pad is reported unplugged, so the
gamepad loop stops every robot and wants a fresh deadman press when messages return. Buttons
already down in the first message after (re)connecting count as up until released, so a
stream that starts with the deadman held moves nothing. Zenoh's thread only queues decoded
messages (bounded); :meth:`JoyInput.poll`, on the gamepad loop's thread, does the rest.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import pygame
import zenoh

from kinesphere import ros2msgs as rm
from kinesphere.clients.gamepad.inputs.pad import PygameInput
from kinesphere.clients.gamepad.state import ControllerState
from kinesphere.clients.options import JOY_LAYOUTS, JoyOptions
from kinesphere.errors import KinesphereError
from kinesphere.rmw_zenoh import resolve
from kinesphere.ros2node import Node

log = logging.getLogger(__name__)

SCHEME = "ros2:"
JOY_INSTANCE = 0x524F5332
"""The pygame instance id the ROS pad gets (no SDL device uses numbers this large)."""
MAX_AXES = 32
MAX_BUTTONS = 64
"""Axes and buttons read from a message; SDL's GameController has 6 and 21."""
INBOX = 64


def input_topic(text: str) -> str | None:
    """The ROS topic of an ``--input ros2:TOPIC`` value (None for the local pad)."""
    if not text.startswith(SCHEME):
        return None
    topic = text[len(SCHEME):] or "/joy"
    return resolve("/", topic)


class JoyInput:
    """A teleop source: Joy messages on ``topic`` turned into pad events for ``pad``."""

    def __init__(self, session: zenoh.Session, pad: PygameInput, topic: str = "/joy",
                 options: JoyOptions | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.options = options or JoyOptions()
        if self.options.layout not in JOY_LAYOUTS:
            raise KinesphereError("malformed", f"Joy layout {self.options.layout!r}; valid: "
                                  f"{', '.join(JOY_LAYOUTS)}")
        if not self.options.timeout_s > 0:
            raise KinesphereError("malformed", "Joy timeout must be > 0 s")
        self.pad = pad
        self.clock = clock
        self.topic = topic
        self.received = 0
        self.connected = False
        self._inbox: deque[tuple[float, tuple[float, ...], tuple[int, ...]]] = deque(maxlen=INBOX)
        self._arrived = threading.Condition()
        self._axes: dict[int, float] = {}
        self._down: set[int] = set()
        self._ignored: set[int] = set()
        self._last = 0.0
        controller = self.options.layout == "controller"
        self._axis_event = pygame.CONTROLLERAXISMOTION if controller else pygame.JOYAXISMOTION
        self._down_event = pygame.CONTROLLERBUTTONDOWN if controller else pygame.JOYBUTTONDOWN
        self._up_event = pygame.CONTROLLERBUTTONUP if controller else pygame.JOYBUTTONUP
        self._added = pygame.CONTROLLERDEVICEADDED if controller else pygame.JOYDEVICEADDED
        self._removed = pygame.CONTROLLERDEVICEREMOVED if controller else pygame.JOYDEVICEREMOVED
        self.node = Node(session, "kinesphere_gamepad", "/", self.options.domain,
                         self.options.distro)
        self.subscription = self.node.subscription(topic, rm.JOY, self._on)

    def _on(self, msg: Any) -> None:
        axes, buttons = rm.read_joy(msg)
        with self._arrived:
            self._inbox.append((self.clock(), axes[:MAX_AXES], buttons[:MAX_BUTTONS]))
            self.received += 1
            self._arrived.notify_all()

    def wait_received(self, count: int, timeout: float) -> bool:
        """Wait until ``count`` messages have arrived in total (tests, start-up)."""
        with self._arrived:
            return self._arrived.wait_for(lambda: self.received >= count, timeout)

    def _post(self, kind: int, **attrs: Any) -> None:
        self.pad.handle(pygame.event.Event(kind, {"instance_id": JOY_INSTANCE, **attrs}))

    def _apply(self, axes: tuple[float, ...], buttons: tuple[int, ...]) -> None:
        if not self.connected:
            self.connected = True
            self._axes.clear()
            self._down.clear()
            self._ignored = {i for i, b in enumerate(buttons) if b}
            self._post(self._added, device_index=-1, name=f"ROS 2 {self.topic}")
            log.info("ROS 2 Joy on %s: receiving", self.topic)
        for i, v in enumerate(axes):
            if self._axes.get(i) != v:
                self._axes[i] = v
                self._post(self._axis_event, axis=i, value=-v)
        for i, b in enumerate(buttons):
            if not b:
                self._ignored.discard(i)
            down = bool(b) and i not in self._ignored
            if down != (i in self._down):
                (self._down.add if down else self._down.discard)(i)
                self._post(self._down_event if down else self._up_event, button=i)

    def poll(self) -> ControllerState:
        """Apply the Joy messages that arrived, notice silence, then the pad's own poll."""
        while self._inbox:
            at, axes, buttons = self._inbox.popleft()
            self._last = at
            self._apply(axes, buttons)
        if self.connected and self.clock() - self._last > self.options.timeout_s:
            self.connected = False
            self._post(self._removed)
            log.warning("ROS 2 Joy on %s: no message for %g s, treated as unplugged",
                        self.topic, self.options.timeout_s)
        return self.pad.poll()

    def close(self) -> None:
        self.node.close()
