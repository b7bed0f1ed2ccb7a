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

A label is not enough: a stored direction serves as a replacement only if its poses *point*
within the same limit of the request, i.e. every stored size's tip (tip - origin, measured by
forward kinematics when the databank was built, published in the catalogue) lies within
:data:`MAX_ANGLE_DEG` of it (:func:`points_within`); one that does not is passed over for the
next by the rule. Unmeasured directions (an older databank) are judged by their label alone.

:data:`MAX_ANGLE_DEG` bounds how far a replacement may be from the request: past it the served
direction has hardly any component along the one asked for (place-low served by a high pull,
a sideways push by forward), which is a different movement, not a substitute.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
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


ROUNDING_DEG: Final = 0.001
"""Stored tips are rounded to a micrometre: an angle this far past the limit is on it."""


Tips = Mapping[Direction, Sequence[Sequence[float]]]
"""Where each stored direction's poses point: one tip offset (x, y, z, body frame) per size."""


def pointing_angle(tip: Sequence[float], requested: Direction) -> float | None:
    """Degrees between a measured tip offset and a direction; None for a tip on the origin or
    place-middle (no bearing to compare)."""
    d = requested.vector
    n = math.sqrt(sum(v * v for v in tip))
    if n < 1e-9 or not any(d):
        return None
    cos = sum(a * b for a, b in zip(tip, d, strict=True)) / n
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def points_within(tips: Sequence[Sequence[float]] | None, requested: Direction,
                  max_angle: float = MAX_ANGLE_DEG) -> bool:
    """Whether every measured size of a direction points within ``max_angle`` of
    ``requested`` (True when unmeasured: nothing to judge but the label)."""
    for tip in tips or ():
        angle = pointing_angle(tip, requested)
        if angle is not None and angle > max_angle + ROUNDING_DEG:
            return False
    return True


def pointing(tips: Sequence[Tips], requested: Direction) -> Callable[[Direction], bool]:
    """A candidate's test for :func:`nearest_direction`: its poses point within the limit of
    ``requested`` on every body in ``tips`` (one mapping per body)."""
    return lambda c: all(points_within(t.get(c), requested) for t in tips)


def nearest_direction(
    requested: Direction, available: Iterable[Direction], max_angle: float = 180.0,
    points: Callable[[Direction], bool] | None = None,
) -> Choice | None:
    """``requested`` itself when available, else the replacement by the module's rule;
    ``points(candidate)``: whether the candidate's poses point close enough to the request
    (:func:`pointing`), else it is passed over for the next one.

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

    for best in sorted(candidates, key=rank):
        angle = angle_between(requested, best)
        if angle > max_angle + 1e-9:
            return None
        if points is None or points(best):
            return Choice(best, angle)
    return None
