"""The base: left stick, turn buttons and turbo to a continuous, proportional :class:`Drive`.

Anchor: ROS ``teleop_twist_joy``: the stick's deflection times a linear scale, a turn control
times an angular scale, and a held turbo button that swaps both for larger scales. Values are
fractions of the platform's own limits (``Drive.forward/left/yaw``), so one stick means the
same on a 0.1 m/s NAO and a 2.5 m/s PackBot.

How the stick steers depends on the base (``Catalogue.base_kind``):

* ``omni`` (youBot's mecanum wheels, NAO's walk) and ``legged`` (a brought walker):
  holonomic. The stick is the body-frame velocity (up = forward, left = sideways left,
  diagonals diagonal); the turn buttons turn.
* ``diff`` / ``skid`` (two wheels, tracks): arcade. Up/down is forward/back, left/right turns
  (a tracked robot cannot slide sideways; pushing left turns it left, in place when the stick
  is only left); the turn buttons turn too.
* ``fixed``: no drive at all.

A target whose mobile bases differ (a group of a youBot and a PackBot) is steered
holonomically: the omni bases slide, the others ignore ``left`` and follow forward and turn.
A base of unknown kind (an older databank says ``""``) is steered holonomically too: a
``diff`` base then ignores the sideways part rather than spinning on a push it did not mean.

Every Drive also carries the version-1 fields (``direction``, ``speed``): the middle horizontal
nearest the heading a version-1 robot would read the same way (for an arcade base that is
forward + turn, which version-1 robots map to a turn), so older robots still drive.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from enum import StrEnum

from kinesphere.clients.gamepad.state import Action, ControllerState
from kinesphere.clients.gamepad.sticks import Tuning, body_xy, deflection, scaled, sector
from kinesphere.laban import RING, Direction, Level
from kinesphere.protocol import Catalogue, Drive


class Steering(StrEnum):
    """How the left stick is read for a target's bases."""

    NONE = "none"
    """Fixed bases only: the stick does nothing."""
    HOLONOMIC = "holonomic"
    """Stick = body-frame velocity, turn buttons = yaw."""
    ARCADE = "arcade"
    """Stick up/down = forward/back, stick left/right and turn buttons = yaw."""


def base_kind(cat: Catalogue) -> str:
    """The catalogue's base kind; an older databank's ``""`` reads as ``fixed`` when the base
    cannot translate and ``unknown`` when it can."""
    if cat.base_kind:
        return cat.base_kind
    return "unknown" if cat.can_translate else "fixed"


def steering_for(kinds: Iterable[str]) -> Steering:
    """The steering for a target whose robots have these base kinds (see the module text).

    No robot known yet: holonomic, which every base reads safely.
    """
    mobile = {k for k in kinds if k != "fixed"}
    seen = set(kinds)
    if seen and not mobile:
        return Steering.NONE
    if mobile and mobile <= {"diff", "skid"}:
        return Steering.ARCADE
    return Steering.HOLONOMIC


def _clip(v: float) -> float:
    return round(max(-1.0, min(1.0, v)), 4) + 0.0  # + 0.0: no -0.0 on the wire


def drive_of(
    cs: ControllerState, current: int | None, steering: Steering, tuning: Tuning
) -> tuple[Drive | None, int | None]:
    """This tick's Drive (None when the base should stay still) and the version-1 sector."""
    if steering is Steering.NONE:
        return None, None
    turbo = cs.is_held(Action.TURBO)
    lin = tuning.drive_turbo if turbo else tuning.drive_scale
    ang = tuning.turn_turbo if turbo else tuning.turn_scale
    fwd, left = body_xy(cs.lx, cs.ly)
    mag = scaled(deflection(fwd, left), tuning.stick_deadzone, tuning.rim)
    n = math.hypot(fwd, left)
    ux, uy = (fwd / n, left / n) if mag > 0.0 else (0.0, 0.0)
    turn = float(cs.is_held(Action.TURN_LEFT)) - float(cs.is_held(Action.TURN_RIGHT))
    if steering is Steering.ARCADE:
        forward, lateral, yaw = ux * mag * lin, 0.0, (uy * mag + turn) * ang
        v1 = (forward, yaw)  # version-1 diff bases turn on the lateral component
    else:
        forward, lateral, yaw = ux * mag * lin, uy * mag * lin, turn * ang
        v1 = (forward, lateral)
    forward, lateral, yaw = _clip(forward), _clip(lateral), _clip(yaw)
    if not (forward or lateral or yaw):
        return None, None
    speed = round(min(1.0, math.hypot(*v1)), 4)
    if speed <= 0.0:  # a pure turn of a holonomic base: nothing a version-1 robot can do
        return Drive(forward=forward, left=lateral, yaw=yaw), None
    k = sector(v1[0], v1[1], current, tuning.hysteresis_deg)
    slug = Direction((RING[k].value, Level.MIDDLE.value)).slug
    return Drive(direction=slug, speed=speed, forward=forward, left=lateral, yaw=yaw), k
