"""The nearest direction a limb has, chosen the way the operator means it.

When a limb has no poses for the commanded direction, the gamepad client (what to send) and the
ECL (what to serve a fleet command) pick a replacement by this one rule, so what the HUD shows and
what the robot acknowledges agree:

1. Never turn a front request into a back one. A request with a forward (back) component is
   served by a direction with a forward (back) component when the limb has one, else by one with
   neither; a request with neither (left, right, place-high, ...) is served from the front or the
   side while the limb has any such direction. A request is never served from the opposite side.
2. Among those, the smallest angle between the direction vectors.
3. Ties: toward the robot's front (larger forward component), then the commanded level, then
   :class:`Direction` order, so the choice never depends on set or dictionary order.

``place-middle`` is the neutral pose, not a pull: it is served only by itself.

:data:`MAX_ANGLE_DEG` bounds how far a replacement may be from the request: past it the served
direction has hardly any component along the one asked for (place-low served by a high pull,
a sideways push by forward), which is a different movement, not a substitute.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Final, NamedTuple

from kinesphere.laban import Direction

MAX_ANGLE_DEG: Final = 45.0
"""Largest angle between a request and its replacement, for the gamepad and the ECL alike. 45
degrees reaches every neighbour on Laban's cube but the corner-to-axis ones (54.7): left-low
may be served by left-forward-low (35.3), place-high by forward-high (45), never
forward-middle by left-middle (90)."""
_ORDER = {d: i for i, d in enumerate(Direction)}


class Choice(NamedTuple):
    """The direction served for a request and the angle between them in degrees."""

    direction: Direction
    angle: float


def angle_between(a: Direction, b: Direction) -> float:
    """Degrees between two direction vectors (0 for the same direction, 180 for antipodes)."""
    cos = sum(x * y for x, y in zip(a.vector, b.vector, strict=True))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def forward_sign(d: Direction) -> int:
    """+1 for directions ahead of the body, -1 behind, 0 for neither."""
    x, _ = d.horizontal.xy
    return (x > 0) - (x < 0)


def _admissible(requested: Direction, candidates: list[Direction]) -> list[Direction]:
    """Rule 1: the candidates on the requested side (front/back), else the neutral ones."""
    sign = forward_sign(requested)
    same = [c for c in candidates if forward_sign(c) == sign]
    neutral = [c for c in candidates if forward_sign(c) == 0]
    if sign != 0:
        return same or neutral
    ahead = [c for c in candidates if forward_sign(c) > 0]
    return neutral + ahead


def nearest_direction(
    requested: Direction, available: Iterable[Direction], max_angle: float = 180.0
) -> Choice | None:
    """``requested`` itself when available, else the replacement by the module's rule.

    None when nothing admissible lies within ``max_angle`` degrees (the caller then answers
    ``direction_unavailable``).
    """
    pool = set(available)
    if requested in pool:
        return Choice(requested, 0.0)
    if requested is Direction.PLACE_MIDDLE:
        return None
    candidates = _admissible(requested, [d for d in pool if d is not Direction.PLACE_MIDDLE])
    if not candidates:
        return None

    def rank(d: Direction) -> tuple[float, float, int, int]:
        return (
            round(angle_between(requested, d), 9),
            -d.vector[0],
            d.level is not requested.level,
            _ORDER[d],
        )

    best = min(candidates, key=rank)
    angle = angle_between(requested, best)
    return Choice(best, angle) if angle <= max_angle + 1e-9 else None
