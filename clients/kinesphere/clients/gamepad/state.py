"""What the operator's hands are doing, as one device-independent snapshot per tick.

Input (gamepad, joystick, keyboard, or a replayed recording) is reduced to a
:class:`ControllerState` so the mapping, the teleop loop and recordings never see pygame.
Sticks keep SDL's convention (x right +, y down +, -1..1) so a recording reads like the device;
:mod:`kinesphere.clients.gamepad.mapping` turns them into the body frame (stick up = forward).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from enum import StrEnum
from typing import Any, Final


class Action(StrEnum):
    """The operator's buttons (the same for every device and the keyboard); a mapping file
    names them by value (``deadman = ["leftshoulder"]``)."""

    DEADMAN = "deadman"  # hold: nothing moves unless held
    BEYOND = "beyond"  # hold at the rim: sizes past far, translating the base
    TURN_LEFT = "turn_left"  # hold: the base turns left (counter-clockwise)
    TURN_RIGHT = "turn_right"  # hold: the base turns right
    TURBO = "turbo"  # hold: the drive's turbo scales
    LIMB_NEXT = "limb_next"
    LIMB_PREV = "limb_prev"
    ORIGIN_NEXT = "origin_next"
    ORIGIN_PREV = "origin_prev"
    TARGET_NEXT = "target_next"
    ESTOP = "estop"  # halts every robot, latches
    RELEASE = "release"  # releases the robots this operator's e-stop latched
    TAKE = "take"  # takes the control lease of the target's robots over from another operator
    QUIT = "quit"


HOLD_ACTIONS: Final = frozenset(
    {Action.DEADMAN, Action.BEYOND, Action.TURN_LEFT, Action.TURN_RIGHT, Action.TURBO}
)
ACTIONS: Final = frozenset(Action)


@dataclass(frozen=True)
class ControllerState:
    """One tick of input.

    ``lx, ly, rx, ry`` are the sticks (-1..1, SDL convention: +x right, +y down), ``lt`` and
    ``rt`` the triggers (0..1). ``held`` names the actions whose buttons are down now;
    ``pressed`` the actions pressed since the previous snapshot, so a tap shorter than a tick
    still counts once. ``connected`` is False while no device gives input (a controller was
    unplugged): everything must stop.
    """

    lx: float = 0.0
    ly: float = 0.0
    rx: float = 0.0
    ry: float = 0.0
    lt: float = 0.0
    rt: float = 0.0
    held: frozenset[str] = field(default_factory=frozenset)
    pressed: frozenset[str] = field(default_factory=frozenset)
    connected: bool = True
    source: str = "none"

    def is_held(self, action: str) -> bool:
        return action in self.held

    def was_pressed(self, action: str) -> bool:
        return action in self.pressed

    def without_presses(self) -> ControllerState:
        """The same hands, with the one-shot presses consumed."""
        return replace(self, pressed=frozenset()) if self.pressed else self

    def to_dict(self) -> dict[str, Any]:
        """Plain data for a JSON line (floats exact, so a replay maps to the same commands)."""
        return {
            "lx": self.lx,
            "ly": self.ly,
            "rx": self.rx,
            "ry": self.ry,
            "lt": self.lt,
            "rt": self.rt,
            "held": sorted(self.held),
            "pressed": sorted(self.pressed),
            "connected": self.connected,
            "source": self.source,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ControllerState:
        """Inverse of :meth:`to_dict`; unknown actions are dropped, missing fields default."""
        return cls(
            lx=float(data.get("lx", 0.0)),
            ly=float(data.get("ly", 0.0)),
            rx=float(data.get("rx", 0.0)),
            ry=float(data.get("ry", 0.0)),
            lt=float(data.get("lt", 0.0)),
            rt=float(data.get("rt", 0.0)),
            held=frozenset(a for a in data.get("held", ()) if a in ACTIONS),
            pressed=frozenset(a for a in data.get("pressed", ()) if a in ACTIONS),
            connected=bool(data.get("connected", True)),
            source=str(data.get("source", "replay")),
        )


NEUTRAL: Final = ControllerState()
DISCONNECTED: Final = ControllerState(connected=False)
