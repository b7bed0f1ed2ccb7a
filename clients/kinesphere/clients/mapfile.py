"""The mapping file: which physical stick, trigger, button or key does what.

Defaults live in ``clients/mappings/default.toml`` (the SDL GameController layout, a raw
joystick fallback and the keyboard). A user file passed with ``--mapping`` is laid over the
defaults key by key, so it only needs the lines it changes. Unknown sections, keys, axes and
buttons are errors naming what is valid: a typo must not silently leave a deadman unbound.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

from kinesphere.clients.state import ACTIONS
from kinesphere.clients.sticks import Tuning
from kinesphere.errors import KinesphereError, choices

STICK_AXES = ("left_x", "left_y", "right_x", "right_y", "low", "high")
"""Logical axes: the two sticks and the low (left) and high (right) triggers."""
CONTROLLER_AXES = {
    "leftx": 0, "lefty": 1, "rightx": 2, "righty": 3, "lefttrigger": 4, "righttrigger": 5,
}  # fmt: skip
"""SDL GameController axis names (SDL_GameControllerGetStringForAxis) and numbers."""
CONTROLLER_BUTTONS = {
    name: i
    for i, name in enumerate(
        "a b x y back guide start leftstick rightstick leftshoulder rightshoulder "
        "dpup dpdown dpleft dpright misc1 paddle1 paddle2 paddle3 paddle4 touchpad".split()
    )
}
"""SDL GameController button names and numbers (Xbox names: a = PlayStation cross, ...)."""
HAT_DIRECTIONS = ("left", "right", "up", "down")
KEY_AXES = (
    "right_forward", "right_back", "right_left", "right_right",
    "drive_forward", "drive_back", "drive_left", "drive_right",
    "low", "high", "near", "mid", "far",
)  # fmt: skip
"""Keyboard keys standing in for stick directions, triggers and reach."""


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


@dataclass(frozen=True)
class MapFile:
    """Everything a mapping file configures."""

    tuning: Tuning
    controller: ControllerMap
    joystick: JoystickMap
    keyboard: KeyboardMap
    source: str


def default_text() -> str:
    """The shipped default mapping (package data)."""
    return resources.files("kinesphere.clients").joinpath("mappings/default.toml").read_text()


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = v
    return out


def _err(where: str, msg: str) -> KinesphereError:
    return KinesphereError("malformed", f"mapping {where}: {msg}")


def _only(table: dict[str, Any], valid: tuple[str, ...] | frozenset[str], where: str) -> None:
    unknown = set(table) - set(valid)
    if unknown:
        raise _err(where, f"unknown {choices(unknown)}; valid: {choices(valid)}")


def _list(value: Any) -> list[Any]:
    return value if isinstance(value, list) else [value]


def _tuning(table: dict[str, Any]) -> Tuning:
    valid = tuple(f.name for f in fields(Tuning))
    _only(table, valid, "[tuning]")
    for k, v in table.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise _err("[tuning]", f"{k} must be a number, got {v!r}")
    return Tuning(**{k: float(v) for k, v in table.items()})


def _controller(table: dict[str, Any]) -> ControllerMap:
    buttons = table.get("buttons", {})
    _only(table, (*STICK_AXES, "buttons"), "[controller]")
    _only(buttons, ACTIONS, "[controller.buttons]")
    axes: dict[str, int] = {}
    for logical in STICK_AXES:
        name = table.get(logical)
        if name not in CONTROLLER_AXES:
            raise _err(f"[controller] {logical}", f"{name!r}; valid: {choices(CONTROLLER_AXES)}")
        axes[logical] = CONTROLLER_AXES[name]
    out: dict[str, tuple[int, ...]] = {}
    for action, names in buttons.items():
        nums = []
        for name in _list(names):
            if name not in CONTROLLER_BUTTONS:
                where = f"[controller.buttons] {action}"
                raise _err(where, f"{name!r}; valid: {choices(CONTROLLER_BUTTONS)}")
            nums.append(CONTROLLER_BUTTONS[name])
        out[action] = tuple(nums)
    return ControllerMap(axes, out)


def _hat(text: str, where: str) -> tuple[int, str]:
    head, _, direction = text.partition("_")
    if not head.startswith("hat") or not head[3:].isdigit() or direction not in HAT_DIRECTIONS:
        raise _err(where, f"{text!r} is neither a button number nor hatN_left/right/up/down")
    return int(head[3:]), direction


def _joystick(table: dict[str, Any]) -> JoystickMap:
    buttons = table.get("buttons", {})
    _only(table, (*STICK_AXES, "trigger_rest", "buttons"), "[joystick]")
    _only(buttons, ACTIONS, "[joystick.buttons]")
    axes: dict[str, int] = {}
    for logical in STICK_AXES:
        idx = table.get(logical)
        if isinstance(idx, bool) or not isinstance(idx, int) or idx < 0:
            raise _err(f"[joystick] {logical}", f"must be an axis number >= 0, got {idx!r}")
        axes[logical] = idx
    rest = table.get("trigger_rest", -1.0)
    if isinstance(rest, bool) or not isinstance(rest, (int, float)) or not -1 <= rest < 1:
        raise _err("[joystick] trigger_rest", f"must be in [-1, 1), got {rest!r}")
    nums: dict[str, tuple[int, ...]] = {}
    hats: dict[str, tuple[tuple[int, str], ...]] = {}
    for action, items in buttons.items():
        where = f"[joystick.buttons] {action}"
        ints = [i for i in _list(items) if isinstance(i, int) and not isinstance(i, bool)]
        strs = [_hat(s, where) for s in _list(items) if isinstance(s, str)]
        if len(ints) + len(strs) != len(_list(items)) or any(i < 0 for i in ints):
            raise _err(where, f"entries must be button numbers or hat names, got {items!r}")
        nums[action], hats[action] = tuple(ints), tuple(strs)
    return JoystickMap(axes, float(rest), nums, hats)


def _names(value: Any, where: str) -> tuple[str, ...]:
    items = _list(value)
    if not all(isinstance(i, str) and i for i in items):
        raise _err(where, f"entries must be key names, got {value!r}")
    return tuple(items)


def _keyboard(table: dict[str, Any]) -> KeyboardMap:
    buttons = table.get("buttons", {})
    _only(table, (*KEY_AXES, "buttons"), "[keyboard]")
    _only(buttons, ACTIONS, "[keyboard.buttons]")
    keys = {k: _names(table.get(k, []), f"[keyboard] {k}") for k in KEY_AXES}
    acts = {a: _names(v, f"[keyboard.buttons] {a}") for a, v in buttons.items()}
    return KeyboardMap(keys, acts)


def parse(data: dict[str, Any], source: str = "<mapping>") -> MapFile:
    """A MapFile from TOML data laid over the defaults."""
    merged = _merge(tomllib.loads(default_text()), data)
    if "groups" in merged:
        raise _err("[groups]", "groups are the robots' own now: start agents with --group NAME "
                   "and target them with --target group:NAME")
    _only(merged, ("tuning", "controller", "joystick", "keyboard"), "sections")
    return MapFile(
        tuning=_tuning(merged.get("tuning", {})),
        controller=_controller(merged.get("controller", {})),
        joystick=_joystick(merged.get("joystick", {})),
        keyboard=_keyboard(merged.get("keyboard", {})),
        source=source,
    )


def _read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """A TOML file as a dict; unreadable or invalid files raise KinesphereError naming it."""
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise KinesphereError("malformed", f"cannot read {what} {path}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise KinesphereError("malformed", f"{what} {path} is not TOML: {exc}") from None


def load(path: str | Path | None = None) -> MapFile:
    """The defaults, or ``path`` laid over them; a bad file raises KinesphereError."""
    if path is None:
        return parse({}, "default")
    return parse(_read_toml(path, "mapping"), str(path))
