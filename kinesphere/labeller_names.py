"""Human names for proposed labels, read from the URDF's own link and joint names.

URDF authors name things in many styles (``arm_right_4_joint``, ``RShoulderPitch``,
``l_hip_pitch``, ``FR_hip_joint``, ``base_LF_HAA``), so names are split into lower-case words
at underscores, digits and camel-case humps, and the words vote: which kind of limb a chain is
(arm, leg, head), which side it is on, front or hind for a quadruped. Where the names say
nothing, the side comes from the geometry (y < 0 is right) and the kind stays unnamed rather
than guessed; a super-user can always add an alias by hand.
"""

from __future__ import annotations

import re
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, field

_KINDS = {
    "arm": {"arm", "shoulder", "elbow", "wrist", "forearm", "clavicle", "larm", "rarm"},
    "leg": {
        "leg", "hip", "knee", "ankle", "thigh", "calf", "shin", "foot", "haa", "hfe", "kfe",
        "lleg", "rleg", "shank",
    },
    "head": {"head", "neck", "cervical", "eye", "eyes", "gaze"},
    "tail": {"tail"},
    "flipper": {"flipper", "flippers"},
}
_FINGER = {
    "finger", "fingers", "thumb", "index", "ring", "pinky", "mrl", "gripper", "hand", "palm",
    "claw", "jaw", "knuckle",
}
_DRIVE = {"wheel", "caster", "castor", "suspension", "rotor", "propeller", "prop", "track"}
_STEER = {"steer", "steering", "swivel"}
_WHEEL = {"wheel", "caster", "castor", "track"}
_CORE = {"torso", "waist", "trunk", "spine", "lumbar", "chest", "thorax"}
_LEFT = {"left", "l", "larm", "lleg", "lf", "lh", "fl", "hl", "rl", "bl"}
_RIGHT = {"right", "r", "rarm", "rleg", "rf", "rh", "fr", "hr", "rr", "br"}
_FRONT = {"front", "fore", "lf", "rf", "fl", "fr"}
_HIND = {"hind", "back", "rear", "lh", "rh", "hl", "hr", "rl", "rr", "bl", "br"}
_WHOLE = {"left", "right", "front", "fore", "hind", "back", "rear"}  # outvote abbreviations
_FIRST_LOCATION = {"arm": "shoulder", "leg": "hip", "head": "neck"}
_DEEPER = {"elbow": "forearm", "knee": "shin", "ankle": "foot", "wrist": None}


def words(name: str) -> list[str]:
    """``RShoulderPitch`` -> [r, shoulder, pitch]; ``arm_right_4_joint`` -> [arm, right, joint]."""
    return [w.lower() for w in re.findall(r"[A-Z]+(?![a-z])|[A-Z]?[a-z]+", name)]


def has_word(name: str, word: str) -> bool:
    return word in words(name)


def is_finger_name(name: str) -> bool:
    return bool(_FINGER & set(words(name)))


def is_drive_name(name: str) -> bool:
    return bool(_DRIVE & set(words(name)))


def is_wheel_name(name: str) -> bool:
    """A wheel, caster or track: what rolls a base on the floor (rotors and propellers do
    not)."""
    return bool(_WHEEL & set(words(name)))


def is_steer_name(name: str) -> bool:
    return bool(_STEER & set(words(name)))


def is_core_name(name: str) -> bool:
    return bool(_CORE & set(words(name)))


def is_limb_name(name: str) -> bool:
    ws = set(words(name))
    return any(ws & kind for kind in _KINDS.values())


@dataclass(frozen=True)
class Chain:
    """What the names (or the geometry) say a chain is: kind, side, front or hind."""

    kind: str | None
    side: str | None
    fore: str | None

    @property
    def prefix(self) -> str:
        return "".join(f"{w}_" for w in (self.fore, self.side) if w)


@dataclass
class Namer:
    """Hands out aliases, each at most once (a label's alias must be unique)."""

    used: set[str] = field(default_factory=set)

    def _take(self, alias: str | None) -> str | None:
        if alias is None or alias in self.used:
            return None
        self.used.add(alias)
        return alias

    @staticmethod
    def _vote(names: Iterable[str], a: tuple[str, set[str]], b: tuple[str, set[str]]
              ) -> str | None:
        """Which of two words the names say more often (a whole word counts twice an
        abbreviation: ``motor_front_rightL`` is on the right)."""
        votes: Counter[str] = Counter()
        for n in names:
            ws = set(words(n))
            for word, group in (a, b):
                hit = ws & group
                votes[word] += 2 if hit & _WHOLE else 1 if hit else 0
        if votes[a[0]] != votes[b[0]]:
            return a[0] if votes[a[0]] > votes[b[0]] else b[0]
        return None

    @staticmethod
    def side_of(names: Iterable[str]) -> str | None:
        return Namer._vote(names, ("left", _LEFT), ("right", _RIGHT))

    def chain(self, names: list[str], y: float | None, locations: int, only: bool,
              fore_hint: str | None = None) -> Chain:
        """Classify a chain from its joint and link names; an unnamed sole arm is an arm.
        ``y``: where its first joint sits across the body (None: on the middle line), for a
        side the names do not give; ``fore_hint``: front or hind from the geometry."""
        counts = Counter(
            kind for n in names for w in words(n) for kind, ws in _KINDS.items() if w in ws
        )
        kind = counts.most_common(1)[0][0] if counts else None
        if kind is None and only and locations >= 3:
            kind = "arm"
        side = self.side_of(names)
        if side is None and not only and y is not None:
            side = "right" if y < 0 else "left"
        fore = self._vote(names[:1], ("front", _FRONT), ("hind", _HIND))  # FR_hip, base_LF_HAA
        if fore is None:  # whole words anywhere (abbreviations also name foot sensors: FsrFL)
            fore = self._vote(names, ("front", _FRONT & _WHOLE), ("hind", _HIND & _WHOLE))
        if kind == "leg" and fore is None:
            fore = fore_hint
        return Chain(kind, side, fore if kind == "leg" else None)

    def limb(self, chain: Chain, depth: int, joint_names: list[str]) -> str | None:
        if chain.kind is None:
            return None
        if depth == 1:  # a second chain of one leg (Minitaur's two motors) is leg_2
            alias = chain.prefix + chain.kind
            return self._take(alias) or self._take(f"{alias}_2")
        word = _location_word(joint_names)
        part = _DEEPER.get(word) if word else None
        return self._take(chain.prefix + part) if part else None

    def location(self, chain: Chain, depth: int, joint_names: list[str]) -> str | None:
        if chain.kind is None:
            return None
        word = _FIRST_LOCATION.get(chain.kind) if depth == 1 else _location_word(joint_names)
        return self._take(chain.prefix + word) if word else None

    def hand(self, chain: Chain, gripper: bool) -> str | None:
        side = chain.prefix if chain.kind is not None or chain.side else ""
        return self._take(side + ("gripper" if gripper else "hand"))

    def core_part(self, links: list[str]) -> str | None:
        for w in (w for ln in links for w in words(ln) if w in _CORE):
            if w not in self.used:
                return self._take(w)
        return None

    def core_joint(self, joint_name: str) -> str | None:
        for w in words(joint_name):
            if w in _CORE:
                return self._take(f"{w}_joint")
        return self._take("waist")


def _location_word(joint_names: list[str]) -> str | None:
    for n in joint_names:
        for w in words(n):
            if w in _DEEPER:
                return w
    return None
