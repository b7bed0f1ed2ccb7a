"""Compound poses: several spatial commands joined into one pose, joint-wise."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from kinesphere.errors import KinesphereError
from kinesphere.protocol import COMPOUND, NO_ID, Pose, SpatialCommand, Substitution
from kinesphere.sizes import MAX_TRANSLATION

PartLike = SpatialCommand | tuple[Any, ...] | list[Any]
Query = Callable[[Any, Any, Any, Any, bool], Pose]


def join(query: Query, platform: str, parts: Sequence[PartLike], last_wins: bool = False) -> Pose:
    """Each part answered by ``query(limb, origin, direction, size, exact)``, joined
    joint-wise; translations add (at most MAX_TRANSLATION metres in all) and substitutions
    are collected.

    A joint set by two parts to different values is a ``conflict`` unless ``last_wins``.
    """
    if not parts:
        raise KinesphereError("malformed", "a compound pose needs at least one part")
    joints: dict[str, float] = {}
    owner: dict[str, int] = {}
    translation: list[float] | None = None
    done: list[SpatialCommand] = []
    substitutions: list[Substitution] = []
    for i, part in enumerate(parts):
        limb, origin, direction, size, exact = _unpack(part, i)
        pose = query(limb, origin, direction, size, exact)
        done.append(SpatialCommand(pose.limb, pose.origin, pose.direction, pose.size, exact))
        substitutions.extend(pose.substitutions)
        for name, value in pose.joints.items():
            if name in joints and joints[name] != value and not last_wins:
                a, b = done[owner[name]], done[-1]
                raise KinesphereError(
                    "conflict", f"joint {name!r} is set by part {owner[name] + 1} "
                    f"({a.limb}, {a.origin}, {a.direction}, {a.size:g}) and by part {i + 1} "
                    f"({b.limb}, {b.origin}, {b.direction}, {b.size:g}); "
                    "pass last_wins to let the later part win",
                )
            joints[name] = value
            owner[name] = i
        if pose.translation is not None:
            base = translation or [0.0, 0.0, 0.0]
            translation = [u + v for u, v in zip(base, pose.translation, strict=True)]
    if translation is not None and math.hypot(*translation) > MAX_TRANSLATION:
        raise KinesphereError(
            "size_out_of_range", f"the parts translate the base {math.hypot(*translation):g} m "
            f"in all; one answer moves it at most {MAX_TRANSLATION:g} m",
        )
    return Pose(platform=platform, limb=COMPOUND, origin=COMPOUND,
                direction=COMPOUND, size=max(p.size for p in done), joints=joints,
                translation=translation, k_id=NO_ID, parts=done, substitutions=substitutions)


def _unpack(part: PartLike, i: int) -> tuple[Any, Any, Any, Any, bool]:
    if isinstance(part, SpatialCommand):
        return part.limb, part.origin, part.direction, part.size, part.exact
    if isinstance(part, (tuple, list)) and len(part) in (4, 5):
        exact = bool(part[4]) if len(part) == 5 else False
        return part[0], part[1], part[2], part[3], exact
    raise KinesphereError(
        "malformed", f"part {i + 1} must be (limb, origin, direction, size[, exact]), got "
        f"{part!r}"
    )
