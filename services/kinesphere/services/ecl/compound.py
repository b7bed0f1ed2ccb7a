"""Compound poses: several spatial commands joined into one pose, joint-wise."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from kinesphere.errors import KinesphereError
from kinesphere.protocol import COMPOUND, NO_ID, Pose, SpatialCommand

PartLike = SpatialCommand | tuple[Any, ...] | list[Any]
Query = Callable[[Any, Any, Any, Any], Pose]


def join(query: Query, platform: str, parts: Sequence[PartLike], last_wins: bool = False) -> Pose:
    """Each part answered by ``query(limb, origin, direction, size)``, joined joint-wise;
    translations add.

    A joint set by two parts to different values is a ``conflict`` unless ``last_wins``.
    """
    if not parts:
        raise KinesphereError("malformed", "a compound pose needs at least one part")
    joints: dict[str, float] = {}
    owner: dict[str, int] = {}
    translation: list[float] | None = None
    done: list[SpatialCommand] = []
    for i, part in enumerate(parts):
        pose = query(*_unpack(part, i))
        done.append(SpatialCommand(pose.limb, pose.origin, pose.direction, pose.size))
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
    return Pose(platform=platform, limb=COMPOUND, origin=COMPOUND,
                direction=COMPOUND, size=max(p.size for p in done), joints=joints,
                translation=translation, k_id=NO_ID, parts=done)


def _unpack(part: PartLike, i: int) -> tuple[Any, Any, Any, Any]:
    if isinstance(part, SpatialCommand):
        return part.limb, part.origin, part.direction, part.size
    if isinstance(part, (tuple, list)) and len(part) == 4:
        return part[0], part[1], part[2], part[3]
    raise KinesphereError(
        "malformed", f"part {i + 1} must be (limb, origin, direction, size), got {part!r}"
    )
