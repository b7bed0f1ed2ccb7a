"""One body vocabulary: the Motif and Labanotation body parts, answered by every body that has
them.

People name body parts the way Motif and Labanotation do (head, torso, right arm, upper arm,
forearm, hand, leg, thigh, shin, foot, and the joints a part moves from: shoulder, elbow,
wrist, hip, knee, ankle, neck). Labels differ between bodies (``limb_13`` is Baxter's hand
and PackBot's upper forearm), so each body's eURDF says what its labels are: the vocabulary is
read from its aliases, the words the super-user (or ``kinesphere label``) gave each label.

* A chain of limbs is an arm, a leg or a head by its first limb's alias (``right_arm``,
  ``left_leg``, ``head``), else by its joint location's (``shoulder``, ``hip``, ``neck``); its
  side comes from the same words. Deeper limbs are the forearm and hand (shin and foot) by
  their aliases, else by their locations' (``elbow``, ``wrist``, ``knee``, ``ankle``).
* The upper arm and the thigh have no label of their own: they are the arm (leg) up to its
  elbow (knee) location, a *cut* (``end``) that the ECL points as a segment.
* A body with one arm answers ``right_arm`` and ``left_arm`` with it (``the only arm``); so
  do one-legged ones. The torso and chest are the core ``c_1`` (what the base translates).
* A word the body has no part for is answered with an empty label and a note (``no left
  leg``): the ECL refuses it with ``absent_part``.
* An alias that *is* a word of the vocabulary always means what the eURDF says, so a
  super-user can correct the reading by naming a label.

The result is a list of :class:`~kinesphere.protocol.BodyWord`, one per word in
:data:`WORDS` order, which ``describe`` prints and the catalogue carries.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Final

from kinesphere.eurdf import Eurdf
from kinesphere.labeller_names import Namer, words
from kinesphere.labels import BodyPart
from kinesphere.protocol import BodyWord

SIDES: Final = ("right", "left")
_CHAIN_KINDS: Final = {
    # kind: (limb word, location word) from the chain's first limb in, then its deeper parts
    "arm": (("arm", "shoulder"), ("upper_arm", ""), ("forearm", "elbow"), ("hand", "wrist")),
    "leg": (("leg", "hip"), ("thigh", ""), ("shin", "knee"), ("foot", "ankle")),
}
_DEEPER: Final = {  # alias words of a deeper limb (side words removed) -> the part it is
    ("forearm",): "forearm", ("lower", "arm"): "forearm", ("hand",): "hand",
    ("gripper",): "hand", ("shin",): "shin", ("calf",): "shin", ("shank",): "shin",
    ("foot",): "foot", ("upper", "arm"): "upper_arm", ("thigh",): "thigh",
}
_LOCATIONS: Final = {"elbow": "forearm", "wrist": "hand", "knee": "shin", "ankle": "foot"}
_FIRST: Final = {"shoulder": "arm", "hip": "leg", "neck": "head"}
_CUTS: Final = {"upper_arm": "forearm", "thigh": "shin"}
"""A part without a label of its own -> the part whose location ends it."""
_SIDE_WORDS: Final = frozenset({"right", "left", "r", "l", "front", "hind", "fore", "rear"})


def _sided_words() -> tuple[str, ...]:
    out: list[str] = []
    for parts in _CHAIN_KINDS.values():
        for limb_word, _ in parts:
            out += [f"{s}_{limb_word}" for s in SIDES]
        for _, location in parts:
            if location:
                out += [f"{s}_{location}" for s in SIDES]
    return tuple(out)


WORDS: Final = ("head", "neck", "torso", "chest", *_sided_words())
"""Every word of the vocabulary, in the order people read them."""
CORE_WORDS: Final = frozenset({"torso", "chest"})
LOCATION_WORDS: Final = frozenset(
    {"neck"} | {f"{s}_{loc}" for s in SIDES for p in _CHAIN_KINDS.values() for _, loc in p if loc}
)
"""Words that name a joint location (an origin) rather than a limb."""


@dataclass
class _Chain:
    """One chain of limbs read as a body part: its kind, side and labelled parts."""

    kind: str
    side: str | None
    first: BodyPart
    parts: dict[str, BodyPart]  # part word (forearm, hand, ...) -> its limb label

    @property
    def title(self) -> str:
        return f"{self.side} {self.kind}" if self.side else self.kind


def _plain(alias: str | None) -> tuple[str, ...]:
    """An alias's words without side words: ``right_forearm`` -> (forearm,)."""
    return tuple(w for w in words(alias or "") if w not in _SIDE_WORDS)


def _kind(e: Eurdf, first: BodyPart) -> str | None:
    ws = set(words(first.alias or ""))
    for kind in ("arm", "leg", "head"):
        if kind in ws or f"{kind[0]}{kind}" in ws or f"r{kind}" in ws:
            return kind
    distal = e.origin(first.distal or "") if first.distal else None
    for w in words(distal.alias or "") if distal is not None else []:
        if w in _FIRST:
            return _FIRST[w]
    return None


def _chains(e: Eurdf) -> list[_Chain]:
    by_chain: dict[int, list[BodyPart]] = {}
    for p in e.limbs:
        by_chain.setdefault(p.index[0], []).append(p)
    out: list[_Chain] = []
    for limbs in by_chain.values():
        limbs.sort(key=lambda p: p.index[1])
        first = limbs[0]
        kind = _kind(e, first)
        if kind is None:
            continue
        side = Namer.side_of([first.alias or ""])
        parts: dict[str, BodyPart] = {}
        for p in limbs[1:]:
            part = _DEEPER.get(_plain(p.alias))
            if part is None:
                loc = e.origin(p.distal or "")
                part = next((_LOCATIONS[w] for w in words(loc.alias or "") if w in _LOCATIONS),
                            None)
            if part is not None and part not in parts:
                parts[part] = p
        out.append(_Chain(kind, side, first, parts))
    return out


def _by_side(chains: list[_Chain], kind: str) -> Iterator[tuple[str, _Chain, str]]:
    """(side word, chain, note) for both sides of a kind of chain: a sided chain answers its
    side; one chain alone answers both; unsided ones take the sides left over, in order."""
    mine = [c for c in chains if c.kind == kind]
    if len(mine) == 1:
        only = mine[0]
        for s in SIDES:
            note = "" if only.side == s else f"the only {kind}"
            yield s, only, note
        return
    taken: dict[str, _Chain] = {}
    for c in mine:
        if c.side is not None and c.side not in taken:
            taken[c.side] = c
    spare = [c for c in mine if c not in taken.values()]
    for s in SIDES:
        if s in taken:
            yield s, taken[s], ""
        elif spare:
            c = spare.pop(0)
            yield s, c, f"the {c.title} (taken as the {s} one)"


def vocabulary(e: Eurdf) -> list[BodyWord]:
    """Every word of :data:`WORDS` as this body answers it (see the module)."""
    found: dict[str, BodyWord] = {}
    core = e.core[0].name
    for w in sorted(CORE_WORDS):
        found[w] = BodyWord(word=w, label=core, note="" if e.aliases.get(w) == core else "the core")
    chains = _chains(e)
    heads = [c for c in chains if c.kind == "head"]
    if heads:
        h = heads[0]
        found["head"] = BodyWord(word="head", label=h.first.name)
        found["neck"] = BodyWord(word="neck", label=str(h.first.distal))
    for kind, parts in _CHAIN_KINDS.items():
        for side, chain, note in _by_side(chains, kind):
            found.update(_chain_words(e, chain, side, note, parts))
    out = []
    for w in WORDS:
        own = e.aliases.get(w)
        if own is not None and _fits(e, w, own):  # the eURDF's own name for a part wins
            out.append(BodyWord(word=w, label=own))
        else:
            out.append(found.get(w) or BodyWord(word=w, label="",
                                                note=f"no {w.replace('_', ' ')}"))
    return out


def _fits(e: Eurdf, word: str, label: str) -> bool:
    """Whether ``label`` is of the kind ``word`` names (a location, a limb); the torso is
    always the core ``c_1``, the part the ECL translates."""
    if word in LOCATION_WORDS:
        return label in e.J
    return word not in CORE_WORDS and label in e.L


def _chain_words(e: Eurdf, chain: _Chain, side: str, note: str,
                 parts: tuple[tuple[str, str], ...]) -> dict[str, BodyWord]:
    """The words one chain answers on ``side`` (``note``: why, when it is not its own side)."""
    limbs = {parts[0][0]: chain.first, **chain.parts}
    of = f"{note}'s " if note else ""  # "the only arm's forearm"
    out: dict[str, BodyWord] = {}
    for limb_word, location in parts:
        limb = limbs.get(limb_word)
        if limb is None:
            continue
        w = f"{side}_{limb_word}"
        out[w] = BodyWord(word=w, label=limb.name,
                          note=note if limb is chain.first else of and of + limb_word)
        where = e.origin(str(limb.distal))
        if location and (limb is chain.first or location in words(where.alias or "")):
            w = f"{side}_{location}"  # deeper: only a location named so (not a gripper's)
            out[w] = BodyWord(word=w, label=where.name, note=of and of + location)
    for cut, by in _CUTS.items():
        inner = limbs.get(by)
        if cut in dict(parts) and cut not in limbs and inner is not None:
            end = e.origin(str(inner.distal))
            w = f"{side}_{cut}"
            out[w] = BodyWord(word=w, label=chain.first.name, end=end.name,
                              note=f"{note or 'the ' + chain.title} up to {end.alias or end.name}")
    return out


def lookup(vocab: list[BodyWord]) -> dict[str, BodyWord]:
    """Word -> how the body answers it, for the words it has or lacks."""
    return {w.word: w for w in vocab}
