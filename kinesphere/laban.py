"""Laban's 27 directional points: 9 horizontals x 3 levels, with body-frame unit vectors.

The body frame is the mover's own: x forward, y left, z up. Dimensional points lie on the
axes, planar points on face diagonals and diagonal points on the corners of the cube, so every
pull is a unit vector; Place-Middle is the centre and has no direction.
"""

from __future__ import annotations

import math
import re
from enum import Enum

from kinesphere.errors import KinesphereError, did_you_mean


class Level(Enum):
    HIGH = "high"
    MIDDLE = "middle"
    LOW = "low"

    @property
    def z(self) -> int:
        return {"high": 1, "middle": 0, "low": -1}[self.value]


class Horizontal(Enum):
    PLACE = "place"
    FORWARD = "forward"
    BACK = "back"
    LEFT = "left"
    RIGHT = "right"
    LEFT_FORWARD = "left-forward"
    RIGHT_FORWARD = "right-forward"
    LEFT_BACK = "left-back"
    RIGHT_BACK = "right-back"

    @property
    def xy(self) -> tuple[int, int]:
        """Integer (x, y) of the horizontal on the unit cube: forward +x, left +y."""
        x = 1 if "forward" in self.value else -1 if "back" in self.value else 0
        y = 1 if "left" in self.value else -1 if "right" in self.value else 0
        return x, y


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
"""The 8 horizontals counter-clockwise seen from above, from forward: the k-th is k*45 deg
to the left (a stick's sectors, a contact sheet's columns)."""


def _slug(h: Horizontal, lvl: Level) -> str:
    return f"{h.value}-{lvl.value}"


def _normalise(text: str) -> str:
    words = re.split(r"[\s_\-]+", text.strip().lower())
    return "-".join(w for w in words if w)


class Direction(Enum):
    """The 27 points, named ``<HORIZONTAL>_<LEVEL>`` except the dimensional shorthand below."""

    PLACE_HIGH = ("place", "high")
    PLACE_MIDDLE = ("place", "middle")
    PLACE_LOW = ("place", "low")
    FORWARD_HIGH = ("forward", "high")
    FORWARD_MIDDLE = ("forward", "middle")
    FORWARD_LOW = ("forward", "low")
    BACK_HIGH = ("back", "high")
    BACK_MIDDLE = ("back", "middle")
    BACK_LOW = ("back", "low")
    LEFT_HIGH = ("left", "high")
    LEFT_MIDDLE = ("left", "middle")
    LEFT_LOW = ("left", "low")
    RIGHT_HIGH = ("right", "high")
    RIGHT_MIDDLE = ("right", "middle")
    RIGHT_LOW = ("right", "low")
    LEFT_FORWARD_HIGH = ("left-forward", "high")
    LEFT_FORWARD_MIDDLE = ("left-forward", "middle")
    LEFT_FORWARD_LOW = ("left-forward", "low")
    RIGHT_FORWARD_HIGH = ("right-forward", "high")
    RIGHT_FORWARD_MIDDLE = ("right-forward", "middle")
    RIGHT_FORWARD_LOW = ("right-forward", "low")
    LEFT_BACK_HIGH = ("left-back", "high")
    LEFT_BACK_MIDDLE = ("left-back", "middle")
    LEFT_BACK_LOW = ("left-back", "low")
    RIGHT_BACK_HIGH = ("right-back", "high")
    RIGHT_BACK_MIDDLE = ("right-back", "middle")
    RIGHT_BACK_LOW = ("right-back", "low")

    @property
    def horizontal(self) -> Horizontal:
        return Horizontal(self.value[0])

    @property
    def level(self) -> Level:
        return Level(self.value[1])

    @property
    def slug(self) -> str:
        """Canonical lowercase name, e.g. ``left-forward-high`` or ``place-middle``."""
        return _slug(self.horizontal, self.level)

    @property
    def vector(self) -> tuple[float, float, float]:
        """Unit vector in the body frame; zero for Place-Middle."""
        x, y = self.horizontal.xy
        z = self.level.z
        n = math.sqrt(x * x + y * y + z * z)
        if n == 0.0:
            return (0.0, 0.0, 0.0)
        return (x / n, y / n, z / n)

    @property
    def kind(self) -> str:
        """'place', 'dimensional' (axis), 'planar' (face diagonal) or 'diagonal' (corner)."""
        x, y = self.horizontal.xy
        nonzero = (x != 0) + (y != 0) + (self.level.z != 0)
        return ("place", "dimensional", "planar", "diagonal")[nonzero]

    @property
    def is_translation(self) -> bool:
        """The 8 middle-level horizontals drive a mobile base."""
        return self.level is Level.MIDDLE and self.horizontal is not Horizontal.PLACE

    @property
    def antipode(self) -> Direction:
        x, y = self.horizontal.xy
        return _BY_XYZ[(-x, -y, -self.level.z)]

    def __str__(self) -> str:
        return self.slug

    @classmethod
    def parse(cls, text: str | Direction) -> Direction:
        """Parse a direction name: any case, spaces/underscores/hyphens, the paper's spellings.

        ``"Left-High"``, ``"Place High"``, ``"Right-forward-Low"``, ``"forward"`` (= forward-middle)
        and ``"place"`` (= place-middle) all work; anything else lists the valid names.
        """
        if isinstance(text, Direction):
            return text
        if not isinstance(text, str):
            raise KinesphereError(
                "unknown_direction", f"direction must be a string, got {type(text).__name__}"
            )
        key = _normalise(text)
        found = _BY_NAME.get(key)
        if found is None:
            slugs = [d.slug for d in cls]
            raise KinesphereError(
                "unknown_direction",
                f"unknown direction {text!r}{did_you_mean(key, slugs)}; valid directions: "
                f"{', '.join(slugs)}",
            )
        return found

    @classmethod
    def pulls(cls) -> tuple[Direction, ...]:
        """The 26 spatial pulls (everything but Place-Middle)."""
        return tuple(d for d in cls if d is not cls.PLACE_MIDDLE)

    @classmethod
    def translations(cls) -> tuple[Direction, ...]:
        """The 8 middle-level horizontals that translate a mobile base."""
        return tuple(d for d in cls if d.is_translation)


def _aliases(d: Direction) -> list[str]:
    h, lvl = d.horizontal.value, d.level.value
    names = [f"{h}-{lvl}"]
    if "-" in h:  # the paper also writes "Forward-Left-High"
        a, b = h.split("-")
        names.append(f"{b}-{a}-{lvl}")
    if lvl == "middle":
        names += [n[: -len("-middle")] for n in list(names)]
    return names


_BY_NAME: dict[str, Direction] = {alias: d for d in Direction for alias in _aliases(d)}
_BY_XYZ: dict[tuple[int, int, int], Direction] = {
    (*d.horizontal.xy, d.level.z): d for d in Direction
}
