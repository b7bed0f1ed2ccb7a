"""Which part of a body performs each column of a Labanotation score.

A score writes the head, each upper arm (its ``elbow`` column: shoulder to elbow) and each
forearm (``wrist``: elbow to wrist). Every body answers those parts through the body
vocabulary (:mod:`kinesphere.vocabulary`, carried in its catalogue), so one score casts
itself onto any body: the upper arm is ``right_upper_arm`` from ``right_shoulder``, the
forearm ``right_forearm`` from ``right_elbow``, the head ``head`` from ``neck``.

A column is skipped, with the reason, when the body lacks the part (Baxter has no head), and
a one-armed body (youBot, PackBot), whose only arm answers both ``right_arm`` and
``left_arm``, performs the right-arm columns with it and skips the left ones. A body whose
base can turn performs the score's ``rotation``; a fixed base does not.

Every performed cell is sent at far: a score writes the direction a limb points, as the
notation writes a limb's direction, and a part of fixed length (a segment) points exactly
there only at its largest size (nearer sizes turn it part of the way from neutral).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final

from kinesphere.notation import Cell
from kinesphere.protocol import BodyWord, SpatialCommand
from kinesphere.scores import COLUMNS, Keyframe
from kinesphere.sizes import FAR

PARTS: Final = {
    "head": ("head", "neck"),
    "right elbow": ("right_upper_arm", "right_shoulder"),
    "right wrist": ("right_forearm", "right_elbow"),
    "left elbow": ("left_upper_arm", "left_shoulder"),
    "left wrist": ("left_forearm", "left_elbow"),
}
"""Score column -> the body-vocabulary words (limb, origin) that perform it."""
ARM_COLUMNS: Final = ("right elbow", "right wrist", "left elbow", "left wrist")


@dataclass(frozen=True)
class Role:
    """A column as one body performs it: the words sent, and the segment that is measured
    (from the ``start`` location's pivot to the ``end`` location's, or to the tip of the
    limb labelled ``end``)."""

    column: str
    limb: str
    origin: str
    start: str
    end: str
    note: str = ""


@dataclass(frozen=True)
class Casting:
    """What one body performs of a score: a role per performed column, the reason for each
    skipped one, whether its base turns, and the size it is sent at."""

    platform: str
    roles: tuple[Role, ...]
    skipped: Mapping[str, str] = field(default_factory=dict)
    turns: bool = False
    far: float = float(FAR)

    def chains(self) -> list[list[Role]]:
        """The roles grouped as a databank answers them together: the head, each arm's parts
        (an upper arm with its forearm)."""
        groups: dict[str, list[Role]] = {}
        for r in self.roles:
            groups.setdefault(r.column.split()[0], []).append(r)
        return list(groups.values())

    def role(self, column: str) -> Role | None:
        return next((r for r in self.roles if r.column == column), None)

    def part(self, role: Role, cell: Cell) -> SpatialCommand:
        return SpatialCommand(role.limb, role.origin, cell.direction.slug, self.far)

    def parts(self, kf: Keyframe, roles: Sequence[Role] | None = None) -> list[SpatialCommand]:
        """The spatial commands that perform ``kf`` (on ``roles``, default every role)."""
        return [self.part(r, kf.cells[r.column]) for r in (self.roles if roles is None
                                                            else roles)]


def cast(platform: str, vocabulary: Sequence[BodyWord], base_kind: str,
         sizes: Sequence[int] = ()) -> Casting:
    """The casting of a score on a body from its catalogue's vocabulary, base and sizes."""
    words = {w.word: w for w in vocabulary}
    roles: list[Role] = []
    skipped: dict[str, str] = {}
    taken: dict[tuple[str, str], str] = {}
    for column in COLUMNS:
        limb_word, origin_word = PARTS[column]
        limb, origin = words.get(limb_word), words.get(origin_word)
        if limb is None or origin is None:
            skipped[column] = f"the body names no {limb_word if limb is None else origin_word}"
            continue
        if not limb.label or not origin.label:
            lacking = limb if not limb.label else origin
            skipped[column] = lacking.note or f"no {lacking.word.replace('_', ' ')}"
            continue
        segment = (origin.label, limb.end or limb.label)
        other = taken.get(segment)
        if other is not None:
            skipped[column] = f"one arm: it performs the {other} column"
            continue
        taken[segment] = column
        note = "; ".join(n for n in (limb.note, origin.note) if n)
        roles.append(Role(column, limb_word, origin_word, segment[0], segment[1], note))
    far = float(max(sizes) if sizes else FAR)
    return Casting(platform, tuple(roles), skipped, base_kind not in ("", "fixed"), far)
