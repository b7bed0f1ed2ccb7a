"""Pure functions from a controller snapshot to what the operator means (an :class:`Intent`).

The right stick is the selected limb: its angle picks the nearest of Laban's 8 horizontals
(place when centred), the triggers pick the level (left = low, right = high, neither =
middle), and its deflection is the size, continuous from 0 (neutral) through near, mid and far
at the rim; holding "beyond" at the rim keeps growing the size past far, which the ECL turns
into base translation. With the right stick centred and a trigger pulled, the pull is Place
High/Low and the trigger's depth is the size. The left stick drives the core (a ``Drive``).

Sectors have hysteresis: the current sector is widened on both sides, so a stick resting on a
boundary does not flicker between two directions at 30 Hz (each flicker would retarget the
robot). No state lives here except the small :class:`MapperState` passed in and returned.

Frames: SDL sticks are +x right, +y down; the body frame is x forward, y left. So stick up =
forward and stick left = left, whichever way the operator holds it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from kinesphere.clients.state import Action, ControllerState
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction, Horizontal, Level
from kinesphere.protocol import Drive

SECTOR_DEG = 45.0
RING: tuple[Horizontal, ...] = (
    Horizontal.FORWARD,
    Horizontal.LEFT_FORWARD,
    Horizontal.LEFT,
    Horizontal.LEFT_BACK,
    Horizontal.BACK,
    Horizontal.RIGHT_BACK,
    Horizontal.RIGHT,
    Horizontal.RIGHT_FORWARD,
)
"""The 8 horizontals counter-clockwise seen from above, from forward; sector k is at k*45 deg."""


@dataclass(frozen=True)
class Tuning:
    """How hands become numbers; every field is overridable in the mapping file's [tuning]."""

    stick_deadzone: float = 0.15
    """Radial dead zone of both sticks (fraction of full deflection): centred below it."""
    hysteresis_deg: float = 10.0
    """The current sector reaches this far into its neighbours before the direction changes."""
    rim: float = 0.95
    """Deflection that counts as the rim: size far (full speed for the drive)."""
    trigger_threshold: float = 0.25
    """A trigger pulled past this chooses its level."""
    far_size: float = 3.0
    """Size at the rim (the VSAM's largest stored size, far)."""
    beyond_rate: float = 1.0
    """Size units per second added past far while "beyond" is held at the rim."""
    beyond_max: float = 3.0
    """Largest size past far the client ever asks for (the base moves (s - far) * step)."""
    keyboard_drive: float = 0.5
    """Drive deflection of the keyboard's drive keys (the "fast" key gives full speed)."""

    def __post_init__(self) -> None:
        checks = {
            "stick_deadzone": 0.0 <= self.stick_deadzone < self.rim,
            "rim": 0.0 < self.rim <= 1.0,
            "hysteresis_deg": 0.0 <= self.hysteresis_deg < SECTOR_DEG / 2,
            "trigger_threshold": 0.0 < self.trigger_threshold < 1.0,
            "far_size": self.far_size > 0.0,
            "beyond_rate": self.beyond_rate >= 0.0,
            "beyond_max": self.beyond_max >= 0.0,
            "keyboard_drive": 0.0 < self.keyboard_drive <= 1.0,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise KinesphereError(
                "malformed",
                f"[tuning] {', '.join(bad)} out of range (need 0 <= stick_deadzone < rim <= 1, "
                f"0 <= hysteresis_deg < 22.5, 0 < trigger_threshold < 1, far_size > 0, "
                f"beyond_rate >= 0, beyond_max >= 0, 0 < keyboard_drive <= 1)",
            )


@dataclass(frozen=True)
class MapperState:
    """What the mapping remembers between ticks: current sectors and the size past far."""

    limb_sector: int | None = None
    drive_sector: int | None = None
    extra: float = 0.0


@dataclass(frozen=True)
class Intent:
    """What the operator asks for this tick (before deadman and targets are applied)."""

    direction: Direction = Direction.PLACE_MIDDLE
    size: float = 0.0
    drive: Drive | None = None
    deadman: bool = False
    reach: float = 0.0
    """Right stick deflection after the dead zone, 0..1 (1 = rim)."""
    beyond: bool = False
    """Growing past far (beyond held at the rim)."""
    drive_vec: tuple[float, float] = (0.0, 0.0)
    """Left stick in the body frame (forward, left) after the dead zone, for the HUD arrow."""

    @property
    def moving(self) -> bool:
        """True when the hands ask for anything but the neutral pose and a still base."""
        return self.size > 0.0 or self.drive is not None


NEUTRAL_INTENT = Intent()


def body_xy(sx: float, sy: float) -> tuple[float, float]:
    """SDL stick (right +, down +) to body frame (forward +, left +)."""
    return -sy, -sx


def deflection(fwd: float, left: float) -> float:
    """Stick magnitude, capped at 1 (square gates report corners past the unit circle)."""
    return min(1.0, math.hypot(fwd, left))


def scaled(mag: float, deadzone: float, rim: float) -> float:
    """0 inside the dead zone, 1 at or past the rim, linear between (no jump at the edge)."""
    if mag <= deadzone:
        return 0.0
    return min(1.0, (mag - deadzone) / (rim - deadzone))


def sector(fwd: float, left: float, current: int | None, hysteresis_deg: float) -> int:
    """Index into :data:`RING` of the stick direction, keeping ``current`` near boundaries."""
    angle = math.degrees(math.atan2(left, fwd))
    if current is not None:
        off = (angle - current * SECTOR_DEG + 180.0) % 360.0 - 180.0
        if abs(off) <= SECTOR_DEG / 2 + hysteresis_deg:
            return current
    return round(angle / SECTOR_DEG) % len(RING)


def level(lt: float, rt: float, threshold: float) -> Level:
    """Left trigger low, right trigger high, neither middle; both pulled: the deeper wins."""
    low, high = lt > threshold, rt > threshold
    if low and high:
        return Level.LOW if lt > rt else Level.HIGH if rt > lt else Level.MIDDLE
    return Level.LOW if low else Level.HIGH if high else Level.MIDDLE


def direction_of(h: Horizontal, lvl: Level) -> Direction:
    """The Laban direction of a horizontal at a level."""
    return Direction((h.value, lvl.value))


def beyond_extra(extra: float, held: bool, at_rim: bool, dt: float, tuning: Tuning) -> float:
    """Size past far: grows at ``beyond_rate`` while held at the rim, else back to 0."""
    if not (held and at_rim):
        return 0.0
    return min(tuning.beyond_max, extra + tuning.beyond_rate * max(0.0, dt))


def drive_of(
    cs: ControllerState, current: int | None, tuning: Tuning
) -> tuple[Drive | None, int | None, tuple[float, float]]:
    """Left stick to a Drive along the nearest middle horizontal, speed from deflection."""
    fwd, left = body_xy(cs.lx, cs.ly)
    speed = scaled(deflection(fwd, left), tuning.stick_deadzone, tuning.rim)
    if speed <= 0.0:
        return None, None, (0.0, 0.0)
    k = sector(fwd, left, current, tuning.hysteresis_deg)
    h = RING[k]
    x, y = h.xy
    n = math.hypot(x, y)
    vec = (speed * x / n, speed * y / n)
    return Drive(direction=direction_of(h, Level.MIDDLE).slug, speed=round(speed, 4)), k, vec


def map_controls(
    cs: ControllerState, prev: MapperState, dt: float, tuning: Tuning
) -> tuple[Intent, MapperState]:
    """The operator's intent for this tick, and the state to pass to the next call.

    A disconnected device means nothing is held: neutral intent, deadman released.
    """
    if not cs.connected:
        return NEUTRAL_INTENT, MapperState()
    fwd, left = body_xy(cs.rx, cs.ry)
    reach = scaled(deflection(fwd, left), tuning.stick_deadzone, tuning.rim)
    lvl = level(cs.lt, cs.rt, tuning.trigger_threshold)
    if reach > 0.0:
        k: int | None = sector(fwd, left, prev.limb_sector, tuning.hysteresis_deg)
        assert k is not None
        horizontal = RING[k]
        size = tuning.far_size * reach
    else:
        k = None
        horizontal = Horizontal.PLACE
        pull = cs.lt if lvl is Level.LOW else cs.rt if lvl is Level.HIGH else 0.0
        size = tuning.far_size * min(1.0, pull)
    extra = beyond_extra(prev.extra, cs.is_held(Action.BEYOND), reach >= 1.0, dt, tuning)
    drive, dk, vec = drive_of(cs, prev.drive_sector, tuning)
    intent = Intent(
        direction=direction_of(horizontal, lvl),
        size=round(size + extra, 4),
        drive=drive,
        deadman=cs.is_held(Action.DEADMAN),
        reach=reach,
        beyond=extra > 0.0,
        drive_vec=vec,
    )
    return intent, MapperState(limb_sector=k, drive_sector=dk, extra=extra)
