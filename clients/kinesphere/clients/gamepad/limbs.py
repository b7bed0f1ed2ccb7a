"""Which limb the right stick moves, from where: cycling through the targets' catalogues.

The choices are the VSAM ``(limb, origin)`` pairs of the targeted robots' platforms (core
entries excluded: the left stick drives the core). For a group or all robots, the pairs every
platform has come first, since labels like ``limb_11`` are meant to be platform-invariant; if
the platforms share none, the union is offered and robots without the pair report it.

Catalogues are fetched over Zenoh on a worker thread: a databank that is slow or down must not
stall the 30 Hz loop, and the client keeps working with the default pair meanwhile. They are
fetched again after a databank announces a recorded pose (``{p}/ecl/{platform}/changed``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field

from kinesphere.clients.link import RobotLink
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.protocol import Catalogue
from kinesphere.substitution import MAX_ANGLE_DEG, Tips, nearest_direction, pointing

log = logging.getLogger(__name__)

DEFAULT_PAIR = ("limb_11", "distal_11")
"""The paper's running example, used until a catalogue arrives."""
RETRY_S = 3.0


def pairs_of(catalogues: Sequence[Catalogue]) -> list[tuple[str, str]]:
    """(limb, origin) pairs offered for these catalogues, in the first catalogue's order."""
    per = [
        [(e.limb, e.origin) for e in c.limbs if e.limb not in c.core and e.origin not in c.core]
        for c in catalogues
    ]
    if not per:
        return [DEFAULT_PAIR]
    union = list(dict.fromkeys(p for pairs in per for p in pairs))
    common = [p for p in union if all(p in pairs for pairs in per)]
    return common or union or [DEFAULT_PAIR]


def direction_sets(
    catalogues: Sequence[Catalogue], limb: str, origin: str
) -> list[frozenset[Direction]]:
    """The directions each platform with (limb, origin) has poses for, one set per catalogue
    that knows the pair (read once per tick: :func:`available_directions` and
    :func:`servable` both judge from them). Names a catalogue spells in a way this client does
    not know are skipped."""
    return [frozenset(_directions(e.directions)) for c in catalogues for e in c.limbs
            if (e.limb, e.origin) == (limb, origin)]


def tips_of(catalogues: Sequence[Catalogue], limb: str, origin: str) -> list[Tips]:
    """Where each platform's stored directions for (limb, origin) point (the catalogue's
    measured tips), one mapping per catalogue that knows the pair, in
    :func:`direction_sets` order: the databank substitutes only directions whose poses point
    within the limit of the request, and so does the client."""
    return [{d: e.tips[slug] for slug in e.tips for d in _directions([slug])}
            for c in catalogues for e in c.limbs if (e.limb, e.origin) == (limb, origin)]


def available_directions(sets: Sequence[frozenset[Direction]]) -> frozenset[Direction] | None:
    """Directions with poses on every platform that has the pair (:func:`direction_sets`).

    None when no catalogue knows the pair (nothing to go by: send what was asked).
    """
    if not sets:
        return None
    return frozenset.intersection(*sets)


def _directions(slugs: Iterable[str]) -> Iterator[Direction]:
    for slug in slugs:
        try:
            yield Direction.parse(slug)
        except KinesphereError:
            log.debug("catalogue direction %r unknown to this client: skipped", slug)


def served(asked: Direction, available: frozenset[Direction] | None,
           tips: Sequence[Tips] = ()) -> Direction:
    """What to send for ``asked``: itself, or its replacement by the core substitution rule.

    The rule (:mod:`kinesphere.substitution`) is the one the ECL uses too: nearest by angle,
    never a front request served from behind, at most ``MAX_ANGLE_DEG`` away, and pointing
    (``tips``, :func:`tips_of`) within that of the request on every body. With no catalogue
    yet, or nothing admissible, ``asked`` goes out unchanged and the robot answers for it
    (``direction_unavailable``).
    """
    if available is None:
        return asked
    choice = nearest_direction(asked, available, MAX_ANGLE_DEG, pointing(tips, asked))
    return asked if choice is None else choice.direction


def servable(asked: Direction, sets: Sequence[frozenset[Direction]],
             tips: Sequence[Tips] = ()) -> bool:
    """Whether some body with the pair (:func:`direction_sets`, with its :func:`tips_of`) has
    ``asked`` or a substitute for it that its ECL would serve. False: every targeted robot
    would refuse the part (``direction_unavailable``), and with it the rest of the command.
    True when no catalogue knows the pair (nothing to go by: the robot answers)."""
    own = list(tips) or [{}] * len(sets)
    return not sets or any(
        nearest_direction(asked, have, MAX_ANGLE_DEG, pointing([t], asked)) is not None
        for have, t in zip(sets, own, strict=True))


def aliases_of(catalogues: Sequence[Catalogue]) -> dict[str, str]:
    """Label -> alias, when every catalogue that has the label calls it the same."""
    seen: dict[str, set[str]] = {}
    for c in catalogues:
        for alias, label in c.aliases.items():
            seen.setdefault(label, set()).add(alias)
    return {label: next(iter(a)) for label, a in seen.items() if len(a) == 1}


@dataclass
class Selection:
    """The current (limb, origin) among ``pairs``; cycling wraps around."""

    pairs: list[tuple[str, str]] = field(default_factory=lambda: [DEFAULT_PAIR])
    limb: str = DEFAULT_PAIR[0]
    origin: str = DEFAULT_PAIR[1]

    def limbs(self) -> list[str]:
        return list(dict.fromkeys(limb for limb, _ in self.pairs))

    def origins(self, limb: str | None = None) -> list[str]:
        limb = self.limb if limb is None else limb
        return [o for lb, o in self.pairs if lb == limb]

    def update(self, pairs: list[tuple[str, str]]) -> None:
        """New choices; keep the current pair (or at least the limb) when still offered."""
        self.pairs = pairs or [DEFAULT_PAIR]
        if (self.limb, self.origin) in self.pairs:
            return
        origins = self.origins()
        if origins:
            self.origin = origins[0]
        else:
            self.limb, self.origin = self.pairs[0]

    def next_limb(self, step: int = 1) -> None:
        limbs = self.limbs()
        i = limbs.index(self.limb) if self.limb in limbs else -step
        self.limb = limbs[(i + step) % len(limbs)]
        origins = self.origins()
        if self.origin not in origins:
            self.origin = origins[0]

    def next_origin(self, step: int = 1) -> None:
        origins = self.origins()
        if not origins:
            return
        i = origins.index(self.origin) if self.origin in origins else -step
        self.origin = origins[(i + step) % len(origins)]


class CatalogueCache:
    """Fetches catalogues in the background; the loop only reads what has arrived."""

    def __init__(self, link: RobotLink, timeout: float = 2.0) -> None:
        self.link = link
        self.timeout = timeout
        self._lock = threading.Lock()
        self._have: dict[str, Catalogue] = {}
        self._failed: dict[str, tuple[float, str]] = {}
        self._busy: set[str] = set()
        self._epoch = link.catalogue_epoch
        self.arrived = threading.Event()
        """Set whenever a catalogue arrives (lets tests and tools await it)."""

    def get(self, platforms: Iterable[str]) -> list[Catalogue]:
        """Catalogues already here for ``platforms``; starts fetching the missing ones."""
        out, now = [], time.monotonic()
        with self._lock:
            if self._epoch != self.link.catalogue_epoch:  # a pose was recorded: fetch again
                self._epoch = self.link.catalogue_epoch
                self._have.clear()
            for p in dict.fromkeys(platforms):
                if p in self._have:
                    out.append(self._have[p])
                elif (
                    p not in self._busy and now - self._failed.get(p, (-RETRY_S, ""))[0] >= RETRY_S
                ):
                    self._busy.add(p)
                    threading.Thread(target=self._fetch, args=(p,), daemon=True).start()
        return out

    def errors(self) -> dict[str, str]:
        with self._lock:
            return {p: msg for p, (_, msg) in self._failed.items() if p not in self._have}

    def _fetch(self, platform: str) -> None:
        try:
            cat = self.link.catalogue(platform, self.timeout)
        except KinesphereError as exc:
            log.info("catalogue of %s: %s", platform, exc.message)
            with self._lock:
                self._failed[platform] = (time.monotonic(), exc.message)
                self._busy.discard(platform)
            return
        except Exception as exc:  # noqa: BLE001 - a closed session during shutdown
            log.debug("catalogue of %s: %r", platform, exc)
            with self._lock:
                self._busy.discard(platform)
            return
        with self._lock:
            self._have[platform] = cat
            self._busy.discard(platform)
        self.arrived.set()
