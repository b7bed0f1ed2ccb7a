"""pygame input -> one :class:`ControllerState` per tick, from events only.

Everything is driven by pygame's event queue (never by polling device state), so posted events
(``pygame.event.post``) drive it exactly like a real pad; that is how the tests work.

Devices: SDL reports a recognised gamepad both as a GameController (``CONTROLLER*`` events,
standard layout) and as a raw joystick (``JOY*`` events); a device known as a controller has
its ``JOY*`` events ignored. Unrecognised devices use the ``[joystick]`` numbers of the mapping.
The device that last gave input is the active one. Hot-plug: when the active device is
removed, the snapshot says ``connected=False`` (the teleop loop stops every robot) until a
device is added again or input arrives; a re-added device starts with nothing held, so the
deadman must be pressed anew. The keyboard always works alongside (its stick keys win over a
centred stick, holds and presses add up); window focus loss releases every key.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
# A teleop pad must keep working when the HUD window is not focused; the deadman still guards.
os.environ.setdefault("SDL_JOYSTICK_ALLOW_BACKGROUND_EVENTS", "1")

import pygame  # noqa: E402
from pygame._sdl2 import controller as sdl_controller  # noqa: E402

from kinesphere.clients.gamepad.mapfile import MapFile  # noqa: E402
from kinesphere.clients.gamepad.state import Action, ControllerState  # noqa: E402
from kinesphere.errors import KinesphereError  # noqa: E402

AXIS_MAX = 32767.0
log = logging.getLogger(__name__)


NO_DISPLAY = "no display: use --headless (or run where DISPLAY or WAYLAND_DISPLAY is set)"
HIDDEN_DRIVERS = frozenset({"offscreen", "dummy"})
"""SDL video drivers that draw into memory: a HUD there would run unseen."""


def init_pygame(headless: bool) -> None:
    """Initialise what input needs: an event queue (video) and the joystick subsystems.

    Headless runs use SDL's dummy video driver (no window); keyboard input then has nowhere
    to come from, so a pad is needed. Without a display SDL would quietly fall back to its
    offscreen driver and the HUD would run unseen: that is an error (:data:`NO_DISPLAY`),
    unless the user chose the driver with ``SDL_VIDEODRIVER``.
    """
    if headless:
        os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
    chosen = os.environ.get("SDL_VIDEODRIVER")
    pygame.display.init()
    if not headless and not chosen and pygame.display.get_driver() in HIDDEN_DRIVERS:
        pygame.quit()
        raise KinesphereError("unavailable", NO_DISPLAY)
    pygame.joystick.init()
    if sdl_controller.get_init():  # pygame keeps this flag across pygame.quit(), while SDL
        sdl_controller.quit()  # shut the subsystem down: controller events would never come
    sdl_controller.init()


def controllers() -> int:
    """Game controllers and joysticks SDL sees now."""
    return int(pygame.joystick.get_count())


def found() -> list[str]:
    """The pads SDL sees now, in the operator's words (``Xbox 360 Controller (game
    controller)``)."""
    out = []
    for i in range(controllers()):
        try:
            kind = "game controller" if sdl_controller.is_controller(i) else "joystick"
            out.append(f"{pygame.joystick.Joystick(i).get_name() or 'unnamed'} ({kind})")
        except pygame.error:  # unplugged meanwhile
            continue
    return out


def axis_value(value: float | int) -> float:
    """pygame gives controller axes as ints (-32768..32767) and joystick axes as floats."""
    v = value / AXIS_MAX if isinstance(value, int) else float(value)
    return max(-1.0, min(1.0, v))


@dataclass
class _Device:
    """Last known state of one pad, from its events."""

    kind: str  # "controller" or "joystick"
    name: str = ""
    handle: object | None = None  # keeps SDL's device open
    axes: dict[int, float] = field(default_factory=dict)
    buttons: set[int] = field(default_factory=set)
    hats: dict[int, tuple[int, int]] = field(default_factory=dict)


class PygameInput:
    """Turns pygame events into controller snapshots using a mapping file."""

    def __init__(self, mapfile: MapFile) -> None:
        self.map = mapfile
        self.devices: dict[int, _Device] = {}
        self.active: int | None = None
        self.lost = False
        self.keys: set[int] = set()
        self._pressed: set[str] = set()
        t = mapfile.tuning
        self._kb_reach = 2.0 / t.far_size  # 1/2/3 keys: near/mid/far for the arrow keys
        self._key_axes = {k: self._codes(v, k) for k, v in mapfile.keyboard.keys.items()}
        self._key_actions = {a: self._codes(v, a) for a, v in mapfile.keyboard.buttons.items()}

    @staticmethod
    def _codes(names: tuple[str, ...], what: str) -> frozenset[int]:
        codes = set()
        for name in names:
            try:
                codes.add(pygame.key.key_code(name))
            except ValueError:
                raise KinesphereError(
                    "malformed", f"mapping [keyboard] {what}: unknown key name {name!r}"
                ) from None
        return frozenset(codes)

    # --- events -------------------------------------------------------------------------

    def poll(self) -> ControllerState:
        """Handle every queued event and return this tick's snapshot."""
        for event in pygame.event.get():
            self.handle(event)
        return self.snapshot()

    def handle(self, event: pygame.event.Event) -> None:
        """Update the state from one event (others are ignored)."""
        t, d = event.type, event.dict
        if t in (pygame.JOYDEVICEADDED, pygame.CONTROLLERDEVICEADDED):
            self._added(event)
        elif t in (pygame.JOYDEVICEREMOVED, pygame.CONTROLLERDEVICEREMOVED):
            self._removed(int(d.get("instance_id", -1)))
        elif t == pygame.CONTROLLERAXISMOTION:
            self._device(d, "controller").axes[int(d["axis"])] = axis_value(d["value"])
        elif t in (pygame.CONTROLLERBUTTONDOWN, pygame.CONTROLLERBUTTONUP):
            dev = self._device(d, "controller")
            self._button(dev, int(d["button"]), t == pygame.CONTROLLERBUTTONDOWN)
        elif t in (pygame.JOYAXISMOTION, pygame.JOYBUTTONDOWN, pygame.JOYBUTTONUP,
                   pygame.JOYHATMOTION):
            self._joystick_event(event)
        elif t == pygame.KEYDOWN:
            self.keys.add(int(d["key"]))
            self._key_press(int(d["key"]))
            self.lost = False
        elif t == pygame.KEYUP:
            self.keys.discard(int(d["key"]))
        elif t == pygame.WINDOWFOCUSLOST:
            self.keys.clear()
        elif t == pygame.QUIT:
            self._pressed.add(Action.QUIT)

    def _added(self, event: pygame.event.Event) -> None:
        kind = "controller" if event.type == pygame.CONTROLLERDEVICEADDED else "joystick"
        index = int(event.dict.get("device_index", -1))
        handle: object | None = None
        name = ""
        try:  # a real device: open it so SDL sends its events
            joy = pygame.joystick.Joystick(index)
            iid = joy.get_instance_id()
            if sdl_controller.is_controller(index):
                pad = sdl_controller.Controller(index)
                kind, handle, name = "controller", pad, pad.name
            else:
                handle, name = joy, joy.get_name()
        except (pygame.error, ValueError):  # posted by a test or already gone
            iid = int(event.dict.get("instance_id", index))
        known = self.devices.get(iid)
        if known is None or (known.kind == "joystick" and kind == "controller"):
            self.devices[iid] = _Device(kind, name or event.dict.get("name", ""), handle)
            if handle is not None:
                log.info("%s connected: %s", kind, name or "unnamed")
        self.lost = False

    def _removed(self, iid: int) -> None:
        dev = self.devices.pop(iid, None)
        if dev is not None and self.active == iid:
            self.active = None
            self.lost = True
            log.warning("%s %s removed: robots stopped; plug one in and press the deadman anew",
                        dev.kind, dev.name or "unnamed")

    def _device(self, d: dict[str, object], kind: str) -> _Device:
        """The device an input event came from, registered on first sight."""
        iid = int(d.get("instance_id", d.get("joy", 0)))  # type: ignore[call-overload]
        dev = self.devices.get(iid)
        if dev is None or (dev.kind == "joystick" and kind == "controller"):
            dev = self.devices[iid] = _Device(kind)
        self.active = iid
        self.lost = False
        return dev

    def _joystick_event(self, event: pygame.event.Event) -> None:
        d = event.dict
        iid = int(d.get("instance_id", d.get("joy", 0)))
        known = self.devices.get(iid)
        if known is not None and known.kind == "controller":
            return  # SDL reports controllers twice; the CONTROLLER* events win
        dev = self._device(d, "joystick")
        if event.type == pygame.JOYAXISMOTION:
            dev.axes[int(d["axis"])] = axis_value(d["value"])
        elif event.type == pygame.JOYHATMOTION:
            old = dev.hats.get(int(d["hat"]), (0, 0))
            new = (int(d["value"][0]), int(d["value"][1]))
            dev.hats[int(d["hat"])] = new
            for action, hats in self.map.joystick.hats.items():
                for hat, direction in hats:
                    if (
                        hat == int(d["hat"])
                        and _hat_on(new, direction)
                        and not _hat_on(old, direction)
                    ):
                        self._pressed.add(action)
        else:
            self._button(dev, int(d["button"]), event.type == pygame.JOYBUTTONDOWN)

    def _button(self, dev: _Device, button: int, down: bool) -> None:
        if not down:
            dev.buttons.discard(button)
            return
        dev.buttons.add(button)
        table = (
            self.map.controller.buttons if dev.kind == "controller" else self.map.joystick.buttons
        )
        for action, nums in table.items():
            if button in nums:
                self._pressed.add(action)

    def _key_press(self, key: int) -> None:
        for action, codes in self._key_actions.items():
            if key in codes:
                self._pressed.add(action)
        far = self.map.tuning.far_size
        for name, size in (("near", 1.0), ("mid", 2.0), ("far", far)):
            if key in self._key_axes[name]:
                self._kb_reach = min(1.0, size / far)

    def describe(self) -> str:
        """The device input comes from, in the operator's words: the active pad (or the
        first one plugged in), else the keyboard."""
        iid = self.active if self.active in self.devices else next(iter(self.devices), None)
        if iid is None:
            return "keyboard (no game controller found)"
        dev = self.devices[iid]
        kind = "game controller" if dev.kind == "controller" else "joystick"
        return f"{dev.name or 'unnamed'} ({kind})"

    # --- snapshot -----------------------------------------------------------------------

    def _key(self, name: str) -> bool:
        return not self.keys.isdisjoint(self._key_axes[name])

    def _raw(self, fraction: float) -> float:
        """Stick deflection that the mapping reads back as ``fraction`` of the rim."""
        t = self.map.tuning
        return t.stick_deadzone + (t.rim - t.stick_deadzone) * fraction if fraction > 0 else 0.0

    def _key_stick(self, prefix: str, fraction: float) -> tuple[float, float] | None:
        fwd = self._key(f"{prefix}_forward") - self._key(f"{prefix}_back")
        left = self._key(f"{prefix}_left") - self._key(f"{prefix}_right")
        if fwd == 0 and left == 0:
            return None
        n = (fwd * fwd + left * left) ** 0.5
        r = self._raw(fraction)
        return -left / n * r, -fwd / n * r  # back to SDL: x right +, y down +

    def _device_state(self) -> tuple[list[float], set[str], str]:
        dev = self.devices.get(self.active) if self.active is not None else None
        if dev is None:
            return [0.0] * 6, set(), "none"
        if dev.kind == "controller":
            cm = self.map.controller
            values = [dev.axes.get(cm.axes[a], 0.0) for a in
                      ("left_x", "left_y", "right_x", "right_y", "low", "high")]
            values[4], values[5] = max(0.0, values[4]), max(0.0, values[5])
            held = {a for a, nums in cm.buttons.items() if not dev.buttons.isdisjoint(nums)}
            return values, held, "controller"
        jm = self.map.joystick
        values = [dev.axes.get(jm.axes[a], 0.0) for a in ("left_x", "left_y", "right_x", "right_y")]
        for a in ("low", "high"):
            v = dev.axes.get(jm.axes[a], jm.trigger_rest)
            values.append(max(0.0, min(1.0, (v - jm.trigger_rest) / (1.0 - jm.trigger_rest))))
        held = {a for a, nums in jm.buttons.items() if not dev.buttons.isdisjoint(nums)}
        for action, hats in jm.hats.items():
            if any(_hat_on(dev.hats.get(h, (0, 0)), direction) for h, direction in hats):
                held.add(action)
        return values, held, "joystick"

    def snapshot(self) -> ControllerState:
        """The state now; the presses seen since the last snapshot are consumed."""
        (lx, ly, rx, ry, lt, rt), held, source = self._device_state()
        held |= {a for a, codes in self._key_actions.items() if not self.keys.isdisjoint(codes)}
        keyboard = False
        right = self._key_stick("right", self._kb_reach)
        if right is not None:
            rx, ry, keyboard = right[0], right[1], True
        left = self._key_stick("drive", 1.0)
        if left is not None:
            lx, ly, keyboard = left[0], left[1], True
        if self._key("low"):
            lt, keyboard = max(lt, self._kb_reach), True
        if self._key("high"):
            rt, keyboard = max(rt, self._kb_reach), True
        pressed, self._pressed = frozenset(self._pressed), set()
        if keyboard or (source == "none" and self.keys):
            source = "keyboard"
        return ControllerState(
            lx=lx, ly=ly, rx=rx, ry=ry, lt=lt, rt=rt,
            held=frozenset(held), pressed=pressed,
            connected=not self.lost, source=source,
        )


def _hat_on(value: tuple[int, int], direction: str) -> bool:
    x, y = value
    return {"left": x < 0, "right": x > 0, "up": y > 0, "down": y < 0}[direction]
