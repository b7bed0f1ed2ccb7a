"""Labanotation cells: the direction-and-level symbol a limb's direction is written with.

A Labanotation score writes where a limb points as one of 26 cells: a horizontal direction
(Forward, Left Forward, Left, ... eight around the body) and a level (High, Normal, Low), or
Place High / Place Low straight up and down. Microsoft's LabanotationSuite (MIT licence)
notates Kinect captures with one rule, ``labanProcessor.py`` (``to_sphere`` then
``coordinate2laban``), and :func:`notate` is that rule: the vector in spherical coordinates
(``theta`` from the vertical, ``phi`` the azimuth, left positive), 45-degree sectors around
the eight horizontals (a boundary belongs to the sector counter-clockwise of it, except that
-22.5 degrees is Right Forward's, as there) and levels split at 22.5 / 67.5 / 112.5 / 157.5
degrees from the vertical, the two caps Place High and Place Low whatever the azimuth.

One deliberate difference: their ``to_sphere`` computes the azimuth with ``atan(y / x)`` and
misses the half-plane ``y == 0, x < 0`` (straight back gets ``phi = 0``, Forward); here it is
180 degrees, Backward, as the sectors say. ``Place Normal`` is no cell of the rule (the
suite's player warns on it); scores use it rarely, for a limb at rest, and it is read as
kinesphere's Place-Middle, the part's neutral pose, which has no direction to compare.

:attr:`Cell.vector` is the score's direction as the suite's player draws it
(``labanotation.js``): levels at 45 / 90 / 135 degrees from the vertical, the horizontals
every 45 degrees, Place High and Place Low vertical. :attr:`Cell.direction` is the kinesphere
direction the cell is performed with (the same horizontal and level; a diagonal's corner of
Laban's cube lies 9.7 degrees from the player's vector, inside the same cell).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Final

from kinesphere.errors import KinesphereError, did_you_mean
from kinesphere.laban import Direction, Horizontal, Level

HORIZONTALS: Final = {
    "Forward": Horizontal.FORWARD, "Left Forward": Horizontal.LEFT_FORWARD,
    "Left": Horizontal.LEFT, "Left Backward": Horizontal.LEFT_BACK,
    "Backward": Horizontal.BACK, "Right Backward": Horizontal.RIGHT_BACK,
    "Right": Horizontal.RIGHT, "Right Forward": Horizontal.RIGHT_FORWARD,
    "Place": Horizontal.PLACE,
}
"""The directions a score writes, as kinesphere names their horizontals."""
LEVELS: Final = {"High": Level.HIGH, "Normal": Level.MIDDLE, "Low": Level.LOW}
"""The levels a score writes (``Normal`` is Laban's middle level)."""
_AZIMUTH: Final = {
    "Forward": 0.0, "Left Forward": 45.0, "Left": 90.0, "Left Backward": 135.0,
    "Backward": 180.0, "Right Backward": -135.0, "Right": -90.0, "Right Forward": -45.0,
}
_ZENITH: Final = {"High": 45.0, "Normal": 90.0, "Low": 135.0}


@dataclass(frozen=True)
class Cell:
    """One symbol of a score: ``horizontal`` and ``level`` spelled as the score spells them
    (``Left Forward``, ``Low``)."""

    horizontal: str
    level: str

    @classmethod
    def parse(cls, direction: object, level: object, where: str) -> Cell:
        """A cell from a score's two words; ``malformed`` naming ``where`` and the valid
        words otherwise."""
        if not isinstance(direction, str) or direction not in HORIZONTALS:
            raise KinesphereError(
                "malformed", f"{where}: unknown direction {direction!r:.80}"
                f"{did_you_mean(direction, HORIZONTALS)}; valid: {', '.join(HORIZONTALS)}")
        if not isinstance(level, str) or level not in LEVELS:
            raise KinesphereError(
                "malformed", f"{where}: unknown level {level!r:.80}"
                f"{did_you_mean(level, LEVELS)}; valid: {', '.join(LEVELS)}")
        return cls(direction, level)

    @property
    def direction(self) -> Direction:
        """The kinesphere direction this cell is performed with."""
        h, lvl = HORIZONTALS[self.horizontal], LEVELS[self.level]
        return next(d for d in Direction if d.horizontal is h and d.level is lvl)

    @property
    def notatable(self) -> bool:
        """Whether the rule can write this cell (every cell but Place Normal)."""
        return not (self.horizontal == "Place" and self.level == "Normal")

    @property
    def vector(self) -> tuple[float, float, float] | None:
        """The score's direction, a body-frame unit vector (x forward, y left, z up); None
        for Place Normal, which has none."""
        if not self.notatable:
            return None
        if self.horizontal == "Place":
            return (0.0, 0.0, 1.0 if self.level == "High" else -1.0)
        theta = math.radians(_ZENITH[self.level])
        phi = math.radians(_AZIMUTH[self.horizontal])
        return (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi),
                math.cos(theta))

    def __str__(self) -> str:
        return f"{self.horizontal} {self.level}"


def spherical(v: Iterable[float]) -> tuple[float, float] | None:
    """``(theta, phi)`` in degrees as LabanEditor's ``to_sphere`` computes them (theta from
    +z, 0..180; phi from +x toward +y, in (-180, 180]), None for a zero vector."""
    x, y, z = (float(c) for c in v)
    r = math.sqrt(x * x + y * y + z * z)
    if r == 0.0 or not math.isfinite(r):
        return None
    theta = math.degrees(math.acos(max(-1.0, min(1.0, z / r))))
    if x != 0.0:
        phi = math.degrees(math.atan(y / x))
    else:
        phi = 90.0 if y > 0 else -90.0
    if x < 0 and y > 0:
        phi = 180 + phi
    elif x < 0 and y < 0:
        phi = -180 + phi
    elif x < 0:  # y == 0: straight back (their quadrant test leaves 0 here)
        phi = 180.0
    return theta, phi


def cell_of(theta: float, phi: float) -> Cell:
    """The cell of spherical angles in degrees: ``coordinate2laban``'s sectors and levels."""
    if theta < 22.5:
        return Cell("Place", "High")
    if theta >= 157.5:
        return Cell("Place", "Low")
    level = "High" if theta < 67.5 else "Normal" if theta < 112.5 else "Low"
    if -22.5 < phi <= 22.5:
        direction = "Forward"
    elif 22.5 < phi <= 67.5:
        direction = "Left Forward"
    elif 67.5 < phi <= 112.5:
        direction = "Left"
    elif 112.5 < phi <= 157.5:
        direction = "Left Backward"
    elif phi > 157.5 or phi <= -157.5:
        direction = "Backward"
    elif -157.5 < phi <= -112.5:
        direction = "Right Backward"
    elif -112.5 < phi <= -67.5:
        direction = "Right"
    else:
        direction = "Right Forward"
    return Cell(direction, level)


def notate(v: Iterable[float]) -> Cell | None:
    """The cell a body-frame vector is written as (the module's rule); None for a zero
    vector, which points nowhere."""
    angles = spherical(v)
    return None if angles is None else cell_of(*angles)


def angle_to(v: Iterable[float], cell: Cell) -> float | None:
    """Degrees between a vector and the cell's direction; None when either has none."""
    want = cell.vector
    x, y, z = (float(c) for c in v)
    n = math.sqrt(x * x + y * y + z * z)
    if want is None or n == 0.0 or not math.isfinite(n):
        return None
    c = (x * want[0] + y * want[1] + z * want[2]) / n
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))
