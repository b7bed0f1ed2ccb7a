"""Pure functions from a controller snapshot to what the operator means (an :class:`Intent`).

The right stick is the selected limb: its angle picks the nearest of Laban's 8 horizontals
(place when centred), the triggers pick the level (left = low, right = high, neither =
middle), and its deflection is the size, continuous from 0 (neutral) through near, mid and far
at the rim; holding "beyond" at the rim keeps growing the size past far, which the ECL turns
into base translation. With the right stick centred and a trigger pulled, the pull is Place
High/Low and the trigger's depth is the size. The left stick, the turn buttons and turbo drive
the base (:mod:`kinesphere.clients.gamepad.drive`), at the same time.

Stick geometry (frames, dead zone, sectors with hysteresis) is in
:mod:`kinesphere.clients.gamepad.sticks`. No state lives here except the small :class:`MapperState`
passed in and returned.
"""

from __future__ import annotations

from dataclasses import dataclass

from kinesphere.clients.gamepad.drive import Steering, drive_of
from kinesphere.clients.gamepad.state import Action, ControllerState
from kinesphere.clients.gamepad.sticks import Tuning, body_xy, deflection, scaled, sector
from kinesphere.laban import RING, Direction, Horizontal, Level
from kinesphere.protocol import Drive


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
    turbo: bool = False
    """Turbo held: the drive uses the turbo scales."""
    steering: Steering = Steering.HOLONOMIC
    """How the left stick was read (from the targets' base kinds)."""

    @property
    def moving(self) -> bool:
        """True when the hands ask for anything but the neutral pose and a still base."""
        return self.size > 0.0 or self.drive is not None


NEUTRAL_INTENT = Intent()


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


def map_controls(
    cs: ControllerState,
    prev: MapperState,
    dt: float,
    tuning: Tuning,
    steering: Steering = Steering.HOLONOMIC,
) -> tuple[Intent, MapperState]:
    """The operator's intent for this tick, and the state to pass to the next call.

    ``steering`` says how the left stick drives the targets' bases (:func:`drive.steering_for`).

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
    drive, dk = drive_of(cs, prev.drive_sector, steering, tuning)
    intent = Intent(
        direction=direction_of(horizontal, lvl),
        size=round(size + extra, 4),
        drive=drive,
        deadman=cs.is_held(Action.DEADMAN),
        reach=reach,
        beyond=extra > 0.0,
        turbo=cs.is_held(Action.TURBO),
        steering=steering,
    )
    return intent, MapperState(limb_sector=k, drive_sector=dk, extra=extra)
