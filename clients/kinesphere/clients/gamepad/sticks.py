"""How hands become numbers: stick frames, dead zone, rim, sectors with hysteresis, and the
:class:`Tuning` that sets them (the mapping file's ``[tuning]``).

Frames: SDL sticks are +x right, +y down; the body frame is x forward, y left. So stick up =
forward and stick left = left, whichever way the operator holds it.

Sectors have hysteresis: the current sector is widened on both sides, so a stick resting on a
boundary does not flicker between two directions at 30 Hz (each flicker would retarget the
robot).
"""

from __future__ import annotations

import math

import msgspec

from kinesphere.errors import KinesphereError
from kinesphere.laban import RING
from kinesphere.sizes import FAR

SECTOR_DEG = 45.0
"""Sector k of a stick is :data:`~kinesphere.laban.RING`'s k-th horizontal, at k*45 deg."""


class Tuning(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """How hands become numbers; every field is overridable in the mapping file's [tuning]
    (a Struct so the file decodes straight into it; the ranges below relate fields)."""

    stick_deadzone: float = 0.15
    """Radial dead zone of both sticks (fraction of full deflection): centred below it."""
    hysteresis_deg: float = 10.0
    """The current sector reaches this far into its neighbours before the direction changes."""
    rim: float = 0.95
    """Deflection that counts as the rim: size far (full drive for the base)."""
    trigger_threshold: float = 0.25
    """A trigger pulled past this chooses its level."""
    far_size: float = float(FAR)
    """Size at the rim (the VSAM's largest stored size, far)."""
    beyond_rate: float = 1.0
    """Size units per second added past far while "beyond" is held at the rim."""
    beyond_max: float = 3.0
    """Largest size past far the client ever asks for (the base moves (s - far) * step)."""
    drive_scale: float = 0.5
    """Base speed at the rim, as a fraction of the platform's maximum (teleop_twist_joy's
    scale_linear)."""
    turn_scale: float = 0.5
    """Turn rate of the turn buttons (and of a full sideways stick on arcade bases), as a
    fraction of the platform's maximum yaw rate (scale_angular)."""
    drive_turbo: float = 1.0
    """``drive_scale`` while turbo is held (scale_linear_turbo)."""
    turn_turbo: float = 1.0
    """``turn_scale`` while turbo is held (scale_angular_turbo)."""

    def __post_init__(self) -> None:
        checks = {
            "stick_deadzone": 0.0 <= self.stick_deadzone < self.rim,
            "rim": 0.0 < self.rim <= 1.0,
            "hysteresis_deg": 0.0 <= self.hysteresis_deg < SECTOR_DEG / 2,
            "trigger_threshold": 0.0 < self.trigger_threshold < 1.0,
            "far_size": self.far_size > 0.0,
            "beyond_rate": self.beyond_rate >= 0.0,
            "beyond_max": self.beyond_max >= 0.0,
            **{k: 0.0 < getattr(self, k) <= 1.0
               for k in ("drive_scale", "turn_scale", "drive_turbo", "turn_turbo")},
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise KinesphereError(
                "malformed",
                f"[tuning] {', '.join(bad)} out of range (need 0 <= stick_deadzone < rim <= 1, "
                f"0 <= hysteresis_deg < 22.5, 0 < trigger_threshold < 1, far_size > 0, "
                f"beyond_rate >= 0, beyond_max >= 0, drive/turn scales and turbos in (0, 1])",
            )


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
