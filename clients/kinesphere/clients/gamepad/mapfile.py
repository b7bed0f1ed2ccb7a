"""The mapping file: which physical stick, trigger, button or key does what.

Defaults live in ``mappings/default.toml`` beside this module (the SDL GameController layout,
a raw joystick fallback and the keyboard). A user file passed with ``--mapping`` is laid over the
defaults key by key, so it only needs the lines it changes. The file's schema is the
``_*Section`` Structs below, decoded by msgspec (:mod:`kinesphere.configfile`): unknown
sections, keys, axes and buttons are errors naming what is valid, because a typo must not
silently leave a deadman unbound.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

import msgspec

from kinesphere.clients.gamepad.state import Action
from kinesphere.clients.gamepad.sticks import Tuning
from kinesphere.configfile import convert, read_toml
from kinesphere.errors import KinesphereError

ControllerAxis = Literal["leftx", "lefty", "rightx", "righty", "lefttrigger", "righttrigger"]
"""SDL GameController axis names (SDL_GameControllerGetStringForAxis), in SDL's order."""
CONTROLLER_AXES = {name: i for i, name in enumerate(get_args(ControllerAxis))}
ControllerButton = Literal[
    "a", "b", "x", "y", "back", "guide", "start", "leftstick", "rightstick", "leftshoulder",
    "rightshoulder", "dpup", "dpdown", "dpleft", "dpright", "misc1", "paddle1", "paddle2",
    "paddle3", "paddle4", "touchpad",
]
"""SDL GameController button names, in SDL's order (Xbox names: a = PlayStation cross, ...)."""
CONTROLLER_BUTTONS = {name: i for i, name in enumerate(get_args(ControllerButton))}
HAT_DIRECTIONS = ("left", "right", "up", "down")

AxisIndex = Annotated[int, msgspec.Meta(ge=0, le=255, description="an axis number >= 0")]
ButtonIndex = Annotated[int, msgspec.Meta(ge=0, le=255)]
HatName = Annotated[
    str,
    msgspec.Meta(pattern=r"^hat\d+_(left|right|up|down)$",
                 description="button numbers or hatN_left/right/up/down names"),
]
KeyName = Annotated[str, msgspec.Meta(min_length=1, max_length=40, description="a key name")]


# --- the file as written (checked by msgspec) ----------------------------------------------


class _ControllerSection(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    left_x: ControllerAxis
    left_y: ControllerAxis
    right_x: ControllerAxis
    right_y: ControllerAxis
    low: ControllerAxis
    high: ControllerAxis
    buttons: dict[Action, list[ControllerButton] | ControllerButton] = {}


class _JoystickSection(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    left_x: AxisIndex
    left_y: AxisIndex
    right_x: AxisIndex
    right_y: AxisIndex
    low: AxisIndex
    high: AxisIndex
    trigger_rest: Annotated[float, msgspec.Meta(ge=-1.0, lt=1.0)] = -1.0
    buttons: dict[Action, list[ButtonIndex | HatName] | ButtonIndex | HatName] = {}


_KeyNames = list[KeyName] | KeyName


class _KeyboardSection(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    right_forward: _KeyNames = []
    right_back: _KeyNames = []
    right_left: _KeyNames = []
    right_right: _KeyNames = []
    drive_forward: _KeyNames = []
    drive_back: _KeyNames = []
    drive_left: _KeyNames = []
    drive_right: _KeyNames = []
    low: _KeyNames = []
    high: _KeyNames = []
    near: _KeyNames = []
    mid: _KeyNames = []
    far: _KeyNames = []
    buttons: dict[Action, _KeyNames] = {}


STICK_AXES = tuple(f for f in _ControllerSection.__struct_fields__ if f != "buttons")
"""Logical axes: the two sticks and the low (left) and high (right) triggers."""
KEY_AXES = tuple(f for f in _KeyboardSection.__struct_fields__ if f != "buttons")
"""Keyboard keys standing in for stick directions, triggers and reach."""


class _MappingFile(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    tuning: Tuning
    controller: _ControllerSection
    joystick: _JoystickSection
    keyboard: _KeyboardSection


# --- what the client uses ------------------------------------------------------------------


@dataclass(frozen=True)
class ControllerMap:
    """SDL GameController: logical axis -> SDL axis number, action -> SDL button numbers."""

    axes: dict[str, int]
    buttons: dict[str, tuple[int, ...]]


@dataclass(frozen=True)
class JoystickMap:
    """Raw joystick: logical axis -> axis index; action -> button indices or hat directions."""

    axes: dict[str, int]
    trigger_rest: float
    buttons: dict[str, tuple[int, ...]]
    hats: dict[str, tuple[tuple[int, str], ...]]


@dataclass(frozen=True)
class KeyboardMap:
    """Key names (as ``pygame.key.name`` spells them) for stick keys and actions."""

    keys: dict[str, tuple[str, ...]]
    buttons: dict[str, tuple[str, ...]]


PAD_NAMES = {"leftshoulder": "LB", "rightshoulder": "RB", "leftstick": "L3",
             "rightstick": "R3", "dpup": "d-pad up", "dpdown": "d-pad down",
             "dpleft": "d-pad left", "dpright": "d-pad right"}
"""How an operator calls SDL's controller buttons (the rest: ``a`` -> ``A``, ``start`` ->
``Start``)."""
KEY_NAMES = {"return": "Enter", "escape": "Escape", "space": "Space"}
"""How an operator calls pygame's key names (the rest: ``k`` -> ``K``, ``f10`` -> ``F10``)."""


@dataclass(frozen=True)
class MapFile:
    """Everything a mapping file configures."""

    tuning: Tuning
    controller: ControllerMap
    joystick: JoystickMap
    keyboard: KeyboardMap
    source: str

    def press(self, action: str, source: str) -> str:
        """What the operator presses for ``action`` on the input ``source`` gives
        (``ControllerState.source``: ``Start`` on a game controller, ``Enter`` on the
        keyboard, ``button 7`` on a raw joystick), in their words; "" when it is unbound
        there. With no device yet (``none``), the keyboard's: it is what works."""
        if source == "keyboard" or source not in ("controller", "joystick"):
            names = [KEY_NAMES.get(k, k.upper() if len(k) <= 3 else k.title())
                     for k in self.keyboard.buttons.get(action, ())]
        elif source == "joystick":
            names = [f"button {b}" for b in self.joystick.buttons.get(action, ())]
            names += [f"hat {h} {d}" for h, d in self.joystick.hats.get(action, ())]
        else:
            by_number = {v: k for k, v in CONTROLLER_BUTTONS.items()}
            names = [PAD_NAMES.get(by_number[b], by_number[b].title() if len(by_number[b]) > 1
                                   else by_number[b].upper())
                     for b in self.controller.buttons.get(action, ())]
        return " or ".join(names)


def default_text() -> str:
    """The shipped default mapping (package data)."""
    mappings = resources.files("kinesphere.clients.gamepad").joinpath("mappings")
    return mappings.joinpath("default.toml").read_text()


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _list(value: Any) -> list[Any]:
    """A button list may be written as one name."""
    return value if isinstance(value, list) else [value]


def _controller(c: _ControllerSection) -> ControllerMap:
    axes = {a: CONTROLLER_AXES[getattr(c, a)] for a in STICK_AXES}
    buttons: dict[str, tuple[int, ...]] = {
        a: tuple(CONTROLLER_BUTTONS[n] for n in _list(v)) for a, v in c.buttons.items()
    }
    return ControllerMap(axes, buttons)


def _joystick(j: _JoystickSection) -> JoystickMap:
    buttons: dict[str, tuple[int, ...]] = {}
    hats: dict[str, tuple[tuple[int, str], ...]] = {}
    for action, items in j.buttons.items():
        entries = _list(items)
        buttons[action] = tuple(i for i in entries if isinstance(i, int))
        hats[action] = tuple(
            (int(h[3:].partition("_")[0]), h.partition("_")[2])
            for h in entries
            if isinstance(h, str)
        )
    return JoystickMap({a: getattr(j, a) for a in STICK_AXES}, j.trigger_rest, buttons, hats)


def _keyboard(k: _KeyboardSection) -> KeyboardMap:
    keys = {a: tuple(_list(getattr(k, a))) for a in KEY_AXES}
    buttons: dict[str, tuple[str, ...]] = {a: tuple(_list(v)) for a, v in k.buttons.items()}
    return KeyboardMap(keys, buttons)


def parse(data: dict[str, Any], source: str = "<mapping>") -> MapFile:
    """A MapFile from TOML data laid over the defaults."""
    merged = _merge(tomllib.loads(default_text()), data)
    if "groups" in merged:
        raise KinesphereError(
            "malformed", f"mapping {source}: [groups] are the robots' own now: start agents "
            "with --group NAME and target them with --target group:NAME",
        )
    f = convert(merged, _MappingFile, f"mapping {source}")
    return MapFile(
        tuning=f.tuning,
        controller=_controller(f.controller),
        joystick=_joystick(f.joystick),
        keyboard=_keyboard(f.keyboard),
        source=source,
    )


def load(path: str | Path | None = None) -> MapFile:
    """The defaults, or ``path`` laid over them; a bad file raises KinesphereError."""
    if path is None:
        return parse({}, "default")
    return parse(read_toml(path, "mapping"), str(path))
