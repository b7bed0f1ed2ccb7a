"""Compound poses: several spatial commands joined into one pose.

Parts on different chains (two arms, an arm and the base) are answered one by one and joined
joint-wise. Parts on one chain are *nested* (an upper arm and its forearm, a leg and its shin):
they are answered together, as one group the ECL solves jointly (:mod:`nested`), because a
stored row of the inner limb points where told only while the outer one stays at neutral. The
same part named twice is a real ``conflict``, unless ``last_wins``: then the later one is the
one that counts.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from kinesphere.errors import KinesphereError
from kinesphere.protocol import COMPOUND, NO_ID, BodyWord, Pose, SpatialCommand, Substitution
from kinesphere.sizes import MAX_TRANSLATION

PartLike = SpatialCommand | tuple[Any, ...] | list[Any]


@dataclass(frozen=True)
class Part:
    """One part of a request with its names resolved: ``limb`` and ``origin`` are labels,
    ``end`` the location a cut limb ends at (the upper arm), ``chain`` the limb's chain
    (None for the core), ``words`` what the vocabulary said about its names."""

    index: int
    limb: str
    origin: str
    end: str | None
    direction: str
    size: float
    exact: bool
    chain: int | None
    depth: int
    words: tuple[BodyWord, ...] = ()

    def text(self) -> str:
        cut = f" up to {self.end}" if self.end else ""
        return (f"part {self.index + 1} ({self.limb}{cut}, {self.origin}, {self.direction}, "
                f"{self.size:g})")


@dataclass(frozen=True)
class Answered:
    """A group's answer: its parts and the pose that serves them."""

    parts: tuple[Part, ...]
    pose: Pose


def unpack(part: PartLike, i: int) -> tuple[Any, Any, Any, Any, bool]:
    """``(limb, origin, direction, size, exact)`` of a SpatialCommand or a tuple."""
    if isinstance(part, SpatialCommand):
        return part.limb, part.origin, part.direction, part.size, part.exact
    if isinstance(part, (tuple, list)) and len(part) in (4, 5):
        exact = bool(part[4]) if len(part) == 5 else False
        return part[0], part[1], part[2], part[3], exact
    raise KinesphereError(
        "malformed", f"part {i + 1} must be (limb, origin, direction, size[, exact]), got "
        f"{part!r}"
    )


def groups(parts: Sequence[Part], last_wins: bool) -> list[tuple[Part, ...]]:
    """The parts grouped for answering: one group per chain (nested parts, outermost
    first), each core part alone; in the order of their first parts. The same limb twice is
    a ``conflict`` unless ``last_wins`` (then the earlier one is dropped)."""
    chains: dict[int, dict[str, Part]] = {}
    alone: list[tuple[Part, ...]] = []
    for p in parts:
        if p.chain is None:
            alone.append((p,))
            continue
        chain = chains.setdefault(p.chain, {})
        twice = chain.get(p.limb)
        if twice is not None and not last_wins:
            raise KinesphereError(
                "conflict", f"{twice.text()} and {p.text()} both move {p.limb}; name each part "
                "once (a limb and a limb inside it are pointed together), or pass last_wins "
                "to let the later part win",
            )
        chain.pop(p.limb, None)
        chain[p.limb] = p
    out = alone + [tuple(sorted(c.values(), key=lambda p: p.depth)) for c in chains.values()]
    return sorted(out, key=lambda g: min(p.index for p in g))


def join(platform: str, answered: Sequence[Answered], last_wins: bool = False) -> Pose:
    """The groups' poses joined joint-wise; translations add (at most MAX_TRANSLATION metres
    in all), substitutions and words are collected in the request's order, the measured angle
    is the worst part's.

    A joint set by two groups to different values (a motor two chains share) is a
    ``conflict`` unless ``last_wins``.
    """
    if not answered:
        raise KinesphereError("malformed", "a compound pose needs at least one part")
    joints: dict[str, float] = {}
    owner: dict[str, Answered] = {}
    translation: list[float] | None = None
    served: list[tuple[int, SpatialCommand]] = []
    substitutions: list[tuple[int, Substitution]] = []
    words: list[tuple[int, BodyWord]] = []
    for a in sorted(answered, key=lambda a: max(p.index for p in a.parts)):
        pose, first = a.pose, min(p.index for p in a.parts)
        for p in a.parts:
            if len(a.parts) == 1 and p.end is None:  # a stored row: maybe another direction
                served.append((p.index, SpatialCommand(pose.limb, pose.origin, pose.direction,
                                                       pose.size, p.exact)))
            else:
                served.append((p.index, SpatialCommand(p.limb, p.origin, p.direction, p.size,
                                                       p.exact)))
            words += [(p.index, w) for w in p.words]
        substitutions += [(first, s) for s in pose.substitutions]
        for name, value in pose.joints.items():
            if name in joints and joints[name] != value and not last_wins:
                raise KinesphereError(
                    "conflict", f"joint {name!r} is set by {owner[name].parts[0].text()} and "
                    f"by {a.parts[0].text()}; pass last_wins to let the later part win",
                )
            joints[name] = value
            owner[name] = a
        if pose.translation is not None:
            base = translation or [0.0, 0.0, 0.0]
            translation = [u + v for u, v in zip(base, pose.translation, strict=True)]
    if translation is not None and math.hypot(*translation) > MAX_TRANSLATION:
        raise KinesphereError(
            "size_out_of_range", f"the parts translate the base {math.hypot(*translation):g} m "
            f"in all; one answer moves it at most {MAX_TRANSLATION:g} m",
        )
    parts = [c for _, c in sorted(served, key=lambda x: x[0])]
    measured = [a.pose.measured_angle for a in answered if a.pose.measured_angle is not None]
    return Pose(platform=platform, limb=COMPOUND, origin=COMPOUND,
                direction=COMPOUND, size=max(p.size for p in parts), joints=joints,
                translation=translation, k_id=NO_ID, parts=parts,
                substitutions=[s for _, s in sorted(substitutions, key=lambda x: x[0])],
                words=[w for _, w in sorted(words, key=lambda x: x[0])],
                measured_angle=max(measured, default=None))
