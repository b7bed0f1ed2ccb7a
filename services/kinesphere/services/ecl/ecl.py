"""f_SB: the in-memory ECL that turns ``(limb, origin, direction, size)`` into a pose.

The databank is read once into per-cell arrays, so a lookup is a few dict hits and, for a
fractional size, one linear blend: no SQL on the hot path. SQL is touched only when the ECL is
opened and when a super-user records or imports poses, after which memory is rebuilt from disk
so the two never disagree.
"""

from __future__ import annotations

import bisect
import json
import logging
import math
import threading
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from kinesphere import hints
from kinesphere.errors import KinesphereError, did_you_mean
from kinesphere.laban import Direction
from kinesphere.platforms.platform import Platform, load_platform
from kinesphere.protocol import (
    NO_ID,
    BodyJoint,
    BodyWord,
    Catalogue,
    LimbEntry,
    Pose,
    SpatialCommand,
    Substitution,
)
from kinesphere.services.ecl import transfer
from kinesphere.services.ecl.cells import Cell, build_cells, unit_horizontal
from kinesphere.services.ecl.compound import Answered, Part, groups, join, unpack
from kinesphere.services.ecl.compound import PartLike as PartLike
from kinesphere.services.ecl.db import Tables, read_tables, upsert_pose, write_tables
from kinesphere.services.ecl.fallback import nearest_cell
from kinesphere.services.ecl.store import check_record, default_db_path, limb_neutral, size_value
from kinesphere.services.ecl.vsam import Vsam, vsam_from_dict
from kinesphere.sizes import MAX_TRANSLATION
from kinesphere.vocabulary import CORE_WORDS, LOCATION_WORDS, vocabulary

if TYPE_CHECKING:  # imported when first needed: mink and the model cost a second
    from kinesphere.services.ecl.nested import Nested

log = logging.getLogger(__name__)
_DB_SUFFIXES = (".sqlite", ".sqlite3", ".db")
_DIRECTION_CACHE_MAX = 512
_PLACE_MIDDLE = Direction.PLACE_MIDDLE.slug


class Ecl:
    """A platform's Embodied Configuration Library, served from memory."""

    def __init__(self, platform: Platform, db_path: Path, tables: Tables) -> None:
        self.platform = platform
        self.db_path = db_path
        self._name = platform.name
        self._slugs: dict[object, str] = {d.slug: d.slug for d in Direction}
        self._slugs.update({d: d.slug for d in Direction})
        self._nested: Nested | None = None
        self._nested_lock = threading.Lock()
        self._index(tables)

    # -- loading -----------------------------------------------------------------------------
    @classmethod
    def open(cls, platform: str | Path | Platform, db: str | Path | None = None) -> Ecl:
        """Open by platform (name, folder or Platform) with its shipped or given databank,
        or by a databank path alone (its ``meta.platform`` names the platform)."""
        if isinstance(platform, Platform):
            plat = platform
        else:
            p = Path(platform)
            if db is None and p.is_file() and p.suffix in _DB_SUFFIXES:
                tables = read_tables(p)
                return cls(load_platform(tables.meta["platform"]), p.resolve(), tables)
            plat = load_platform(str(platform))
        path = Path(db) if db is not None else default_db_path(plat)
        return cls(plat, path.resolve(), read_tables(path))

    @classmethod
    def from_json(
        cls, platform: str | Path | Platform, json_path: str | Path, db: str | Path
    ) -> Ecl:
        """Create (or replace) the databank ``db`` from an export and open it."""
        plat = platform if isinstance(platform, Platform) else load_platform(str(platform))
        tables = transfer.tables_from_json(plat, transfer.read_json(json_path))
        write_tables(db, tables)
        return cls(plat, Path(db).resolve(), read_tables(db))

    def reload(self) -> bool:
        """Re-read the databank (after a rebuild or another process's record); True if changed."""
        old = self.version
        self._index(read_tables(self.db_path))
        return self.version != old

    def _index(self, t: Tables) -> None:
        plat, e = self.platform, self.platform.eurdf
        if t.meta["platform"] != plat.name:
            raise KinesphereError(
                "malformed", f"{self.db_path} is a databank for {t.meta['platform']!r}, "
                f"not {plat.name!r}",
            )
        if t.joints != e.joint_names:
            raise KinesphereError(
                "incompatible_version", f"{self.db_path} was built for other joints than "
                f"{plat.name}'s eURDF; rebuild it with "
                f"'{hints.build_ecl(plat.name if plat.shipped else str(plat.folder))}'",
            )
        if t.meta["eurdf_sha256"] != e.sha256:
            log.warning("%s was built from another version of %s.eurdf", self.db_path, plat.name)
        vsam = vsam_from_dict(json.loads(t.meta["vsam"]), plat, f"{self.db_path} meta")
        cells = build_cells(plat, t, self.db_path, _rest_tips(t.meta))
        limb_origins: dict[str, list[str]] = {}
        for limb, origin in cells:
            limb_origins.setdefault(limb, []).append(origin)
        served = set(limb_origins)
        # everything is built before anything is swapped, so a failed reload changes nothing
        self.vsam: Vsam = vsam
        self._tables = t
        self.version: str = t.digest()[:16]
        self._cells = cells
        self._limb_origins = limb_origins
        self._limbs = _names(e.limbs, served) | _names(e.core, served)
        self._origins = _names(e.distals, set(e.J)) | _names(e.core, set(e.C))
        self._vocabulary = vocabulary(e)
        self._read_words(served)
        self._chains = {p.name: p.index for p in e.limbs}
        # a limb's neutral, and its stance leg's when it has one: back at place-middle, the
        # leg that held the body over its foot stands as before too
        self._neutral = {li: limb_neutral(plat, li) for li in e.L}
        for cell in (c for cs in cells.values() for c in cs.values()):
            if cell.limb in self._neutral:
                held = [j for j in cell.joints if j not in self._neutral[cell.limb]]
                self._neutral[cell.limb].update({j: plat.neutral.get(j, 0.0) for j in held})
        self._quality = {(q[0], q[1]): q[2:] for q in t.quality}
        self._own = {li: frozenset(e.limb_joints(li)) for li in e.L}
        self._max_size = vsam.max_size
        self._core = frozenset(e.C)
        self._catalogue: Catalogue | None = None
        if self._nested is not None and self._nested.sizes != vsam.sizes:
            self._nested = None

    def _read_words(self, served: set[str]) -> None:
        """The body vocabulary's words as names of this ECL: whole limbs and locations join
        the labels and aliases, cut limbs (the upper arm) are answered by the nested solver,
        missing parts are refused with ``absent_part``. ``_said``: the words worth telling
        (not the body's own names)."""
        e = self.platform.eurdf
        own = set(e.aliases) | set(e.L) | set(e.J) | set(e.C)
        self._words = {w.word: w for w in self._vocabulary}
        self._said: dict[str, BodyWord] = {}
        self._cuts: dict[str, BodyWord] = {}
        for w in self._vocabulary:
            if w.word in own or not w.label:
                continue
            if w.word in LOCATION_WORDS or w.word in CORE_WORDS:
                self._origins[w.word] = w.label
            if w.end:
                self._cuts[w.word] = w
            elif w.word not in LOCATION_WORDS and w.label in served:
                self._limbs[w.word] = w.label
            self._said[w.word] = w

    # -- f_SB --------------------------------------------------------------------------------
    def query(self, limb: str, origin: str, direction: str | Direction, size: object,
              exact: bool = False) -> Pose:
        """f_SB(l, o, d, s): the pose for a spatial command (see docs/architecture.md).

        A direction the limb does not have is served by the nearest one it has within
        ``kinesphere.substitution.MAX_ANGLE_DEG`` (:mod:`kinesphere.services.ecl.fallback`),
        reported in ``Pose.substitutions`` with ``direction`` the served one; ``exact`` asks
        for this direction only (else ``direction_unavailable``), and so does the core: the
        base is driven only in its 8 translation directions, never in a substitute.
        """
        try:
            lname = self._limbs[limb]
        except (KeyError, TypeError):
            if isinstance(limb, str) and limb.strip() in self._cuts:
                return self._solved((self._part(0, (limb, origin, direction, size, exact)),))
            lname = self._bad_limb(limb)
        try:
            oname = self._origins[origin]
        except (KeyError, TypeError):
            oname = self._bad_origin(origin, lname)
        said = self._said
        words = [said[n] for n in (limb, origin) if n in said] if said else []
        cells = self._cells.get((lname, oname))
        if cells is None:
            raise self._unpaired(lname, origin)
        slug, s = self._slug_size(direction, size)
        cell = cells.get(slug)
        if slug == _PLACE_MIDDLE and lname in self._neutral:
            return Pose(platform=self._name, limb=lname, origin=oname, direction=slug, size=s,
                        joints=dict(self._neutral[lname]),
                        k_id=cell.k_id if cell is not None else NO_ID, words=words)
        substitutions: list[Substitution] = []
        if cell is None:
            cell, sub = nearest_cell(lname, oname, cells, slug, exact or lname in self._core)
            substitutions.append(sub)
        translation: list[float] | None = None
        p_id: int | None = None
        knots = cell.knots
        i = bisect.bisect_right(knots, s) - 1
        if not cell.joints:  # core cell: the base translates s steps, no joints move
            joints: dict[str, float] = {}
            translation = self._translate(cell.slug, s)
            if s == knots[i] and i:
                p_id = cell.sizes[i - 1]
        elif s == knots[i]:
            joints = dict(cell.stored[i])
            p_id = cell.sizes[i - 1] if i else None
        elif i < len(knots) - 1:
            a, b = cell.values[i], cell.values[i + 1]
            t = (s - knots[i]) / (knots[i + 1] - knots[i])
            joints = {n: x + t * (y - x) for n, x, y in zip(cell.joints, a, b, strict=True)}
        else:
            joints = dict(cell.stored[-1])
            translation = self._translate(cell.slug, s - knots[-1])
        return Pose(platform=self._name, limb=lname, origin=oname, direction=cell.slug, size=s,
                    joints=joints, translation=translation, k_id=cell.k_id, p_id=p_id,
                    substitutions=substitutions, words=words,
                    measured_angle=_angle(cell.tip_at(s), slug) if cell.joints else None)

    def _slug_size(self, direction: object, size: object) -> tuple[str, float]:
        """The canonical slug and a checked size (cached spellings cost a dict hit)."""
        try:
            slug = self._slugs[direction]
        except (KeyError, TypeError):
            slug = self._direction(direction)
        if (type(size) is float or type(size) is int) and 0 <= size <= self._max_size:
            return slug, float(size)
        return slug, self._size(size)

    def _translate(self, slug: str, units: float) -> list[float]:
        """``units`` translation steps along the direction's unit horizontal, body frame."""
        h, step = unit_horizontal(Direction.parse(slug)), self.vsam.translation_step
        if step is None or not self.platform.base.mobile:
            raise KinesphereError(
                "cannot_translate", f"{self._name} has a fixed base: sizes above the largest "
                f"stored size ({self.vsam.k_smax}) would need the base to move",
            )
        if h is None:
            raise KinesphereError(
                "cannot_translate", f"{slug} is purely vertical; the base cannot translate "
                f"along it, so sizes above {self.vsam.k_smax} are not available",
            )
        k = units * step
        if not math.isfinite(k) or k > MAX_TRANSLATION:
            raise KinesphereError(
                "size_out_of_range", f"size too large: {units:g} steps of {step:g} m is more "
                f"than the {MAX_TRANSLATION:g} m one answer may translate the base",
            )
        return [h[0] * k + 0.0, h[1] * k + 0.0, 0.0]  # + 0.0: no -0.0 at size 0

    def _size(self, size: object) -> float:
        s = size_value(size)
        if s > self._max_size and self.vsam.can_translate:
            raise KinesphereError(
                "size_out_of_range", f"size {s:g} is past {self._name}'s largest size "
                f"{self._max_size:g} (at most {MAX_TRANSLATION:g} m of base translation)",
            )
        return s

    def compound(self, parts: Sequence[PartLike], last_wins: bool = False) -> Pose:
        """Several parts in one pose (:mod:`kinesphere.services.ecl.compound`): parts of one
        chain (an upper arm and its forearm) are pointed together by the nested solver,
        the others answered from stored rows and joined joint-wise; translations add.

        The same part twice is a ``conflict`` unless ``last_wins``; a part with ``exact`` is
        not substituted.
        """
        if not parts:
            raise KinesphereError("malformed", "a compound pose needs at least one part")
        resolved = [self._part(i, p) for i, p in enumerate(parts)]
        answered: list[Answered] = []
        placed: dict[str, float] = {}
        for g in groups(resolved, last_wins):
            answered.append(Answered(g, self._answer(g, placed)))
            placed.update(answered[-1].pose.joints)
        return join(self._name, answered, last_wins)

    def solves(self, parts: Sequence[PartLike]) -> bool:
        """Whether answering ``parts`` needs the nested solver (tens of milliseconds, more
        on a cold start: the databank answers such requests off the network's threads): a
        cut limb (an upper arm) or two limbs of one chain. Never raises."""
        seen: dict[int, str] = {}
        for part in parts:
            limb = part.limb if isinstance(part, SpatialCommand) else (
                part[0] if isinstance(part, (tuple, list)) and part else None)
            if not isinstance(limb, str):
                continue
            if limb.strip() in self._cuts:
                return True
            label = self._limbs.get(limb.strip())
            chain = self._chains.get(label) if label is not None else None
            if label is None or chain is None:
                continue
            if seen.setdefault(chain[0], label) != label:
                return True
        return False

    def _part(self, i: int, part: PartLike) -> Part:
        """One part with its names resolved and checked (the errors of :meth:`query`)."""
        limb, origin, direction, size, exact = unpack(part, i)
        cut: BodyWord | None = None
        try:
            lname = self._limbs[limb]
        except (KeyError, TypeError):
            cut = self._cuts.get(limb.strip()) if isinstance(limb, str) else None
            lname = cut.label if cut is not None else self._bad_limb(limb)
        try:
            oname = self._origins[origin]
        except (KeyError, TypeError):
            oname = self._bad_origin(origin, lname)
        if (lname, oname) not in self._cells:
            raise self._unpaired(lname, origin)
        slug, s = self._slug_size(direction, size)
        said = self._said
        words = tuple(said[n.strip()] for n in (limb, origin)
                      if isinstance(n, str) and n.strip() in said)
        index = self._chains.get(lname)
        return Part(i, lname, oname, cut.end if cut is not None else None, slug, s,
                    bool(exact), index[0] if index else None, index[1] if index else 0, words)

    def _answer(self, group: tuple[Part, ...], placed: Mapping[str, float]) -> Pose:
        if len(group) == 1 and group[0].end is None:
            p = group[0]
            return self.query(p.limb, p.origin, p.direction, p.size, p.exact)
        return self._solved(group, placed)

    def _solved(self, group: tuple[Part, ...], placed: Mapping[str, float] | None = None
                ) -> Pose:
        """Nested parts (or a cut limb) pointed together by the nested solver, touching
        nothing of the body as the compound's earlier parts ``placed`` it (two forearms
        crossed in front pass one another); the measured angle is the worst segment's."""
        from kinesphere.services.ecl.nested import Segment

        solver = self.nested()
        segments = [Segment(p.limb, p.origin, p.end, Direction.parse(p.direction), p.size)
                    for p in group]
        solution = solver.solve(segments, placed)
        translation: list[float] | None = None
        for p in group:
            if p.size > self.vsam.k_smax:
                t = self._translate(p.direction, p.size - self.vsam.k_smax)
                translation = [a + b for a, b in zip(translation or [0.0] * 3, t, strict=True)]
        first = group[0]
        measured = [a for a in solution.measured if a is not None]
        return Pose(platform=self._name, limb=first.limb, origin=first.origin,
                    direction=first.direction, size=max(p.size for p in group),
                    joints=dict(solution.joints), translation=translation, k_id=NO_ID,
                    words=[w for p in group for w in p.words],
                    measured_angle=max(measured, default=None))

    def nested(self) -> Nested:
        """The nested solver of this platform, made when first needed (compiles the model)."""
        with self._nested_lock:
            if self._nested is None:
                from kinesphere.platforms.mjcf import model_of
                from kinesphere.services.ecl.nested import Nested

                self._nested = Nested(model_of(self.platform), self.vsam.sizes)
            return self._nested

    # -- names and errors --------------------------------------------------------------------
    def directions(self, limb: str, origin: str) -> list[Direction]:
        """Directions a pair answers (place-middle always, for limbs), in Laban order."""
        have = self._cells.get((limb, origin), {})
        core = limb in self.platform.eurdf.C
        return [d for d in Direction
                if d.slug in have or (d is Direction.PLACE_MIDDLE and not core)]

    def _direction(self, text: object) -> str:
        slug = Direction.parse(text).slug  # type: ignore[arg-type]
        if isinstance(text, str) and len(self._slugs) < _DIRECTION_CACHE_MAX:
            self._slugs[text] = slug
        return slug

    def _valid_limbs(self) -> str:
        e = self.platform.eurdf
        out = [f"{p.name} ({p.alias})" if p.alias else p.name
               for p in e.limbs if p.name in self._limb_origins]
        if self.vsam.can_translate:
            out += [f"{p.name} (core)" for p in e.core if p.name in self._limb_origins]
        return ", ".join(out) or "none"

    def _bad_limb(self, limb: object) -> str:
        e = self.platform.eurdf
        if isinstance(limb, str) and limb.strip() in self._limbs:
            return self._limbs[limb.strip()]
        name = limb.strip() if isinstance(limb, str) else None
        word = self._words.get(name) if name is not None else None
        if word is not None and not word.label:
            raise self._absent(word)
        if name is not None and (e.aliases.get(name, name) in e.C or name in CORE_WORDS):
            raise KinesphereError(
                "cannot_translate", f"{self.platform.name} has a fixed base; the core "
                f"{limb!r} cannot be moved. Limbs: {self._valid_limbs()}",
            )
        what = repr(limb) if isinstance(limb, str) else f"of type {type(limb).__name__}"
        raise KinesphereError(
            "unknown_limb", f"{self.platform.name} has no limb {what} in its ECL"
            f"{did_you_mean(limb, self._limbs)}; valid: {self._valid_limbs()}",
        )

    def _bad_origin(self, origin: object, limb: str) -> str:
        if isinstance(origin, str) and origin.strip() in self._origins:
            return self._origins[origin.strip()]
        word = self._words.get(origin.strip()) if isinstance(origin, str) else None
        if word is not None and not word.label:
            raise self._absent(word)
        raise self._unpaired(limb, origin)

    def _absent(self, word: BodyWord) -> KinesphereError:
        has = [w.word for w in self._vocabulary if w.label]
        return KinesphereError(
            "absent_part", f"{self._name} has {word.note or 'no such part'}: {word.word!r} is "
            f"a body part it lacks; the body words it answers: {', '.join(has) or 'none'}",
        )

    def _unpaired(self, limb: str, origin: object) -> KinesphereError:
        paired = self._limb_origins.get(limb, [])
        names = [n for n, label in self._origins.items() if label in paired]
        what = repr(origin) if isinstance(origin, str) else f"of type {type(origin).__name__}"
        return KinesphereError(
            "unknown_origin", f"origin {what} is not paired with {limb}"
            f"{did_you_mean(origin, names)}; its origins: {', '.join(paired) or 'none'}",
        )

    # -- catalogue, rows ---------------------------------------------------------------------
    def catalogue(self) -> Catalogue:
        """What this ECL answers, for clients to offer only valid commands."""
        if self._catalogue is not None:
            return self._catalogue
        e = self.platform.eurdf
        limbs, core_dirs = [], []
        for (limb, origin), cells in self._cells.items():
            if limb in e.C:
                core_dirs = [d.slug for d in self.directions(limb, origin)]
                continue
            sizes = sorted({s for c in cells.values() for s in c.sizes})
            tips = {c.slug: [list(t) for t in c.tips[1:] if t is not None]
                    for c in cells.values() if any(t is not None for t in c.tips[1:])}
            limbs.append(LimbEntry(limb, origin, [d.slug for d in self.directions(limb, origin)],
                                   sizes, tips))
        step = self.vsam.translation_step
        self._catalogue = Catalogue(
            platform=self.platform.name,
            core=list(e.C),
            limbs=limbs,
            joints=[BodyJoint(j.name, j.lower, j.upper, j.velocity) for j in e.P],
            translation_step=step,
            can_translate=bool(core_dirs) and step is not None,
            directions_for_core=core_dirs,
            sizes=sorted({s for cs in self._cells.values() for c in cs.values() for s in c.sizes}),
            aliases=dict(e.aliases),
            version=self.version,
            max_size=self._max_size,
            base_kind=self.platform.base.kind,
            vocabulary=list(self._vocabulary),
        )
        return self._catalogue

    @property
    def meta(self) -> dict[str, str]:
        """The databank's ``meta`` table (platform, eURDF hash, VSAM, generator notes)."""
        return dict(self._tables.meta)

    def dropped(self, kind: str = "dropped") -> dict[str, dict[str, str]]:
        """What the generator left out and why: ``{"limb/origin": {direction: reason}}``;
        ``kind`` "unstable" for the directions dropped for stability, "short" for kept ones
        whose largest sizes stability removed."""
        return self.notes(kind)

    def notes(self, key: str) -> dict[str, Any]:
        """One of the generator's notes in ``meta``, JSON ``{"limb/origin": ...}``:
        ``dropped``, ``unstable``, ``short``, ``size_rules`` ("reach"/"swing"), ``swung``
        (pulls a reach limb swings), ``neutral_tips``; empty for databanks built before it
        was recorded, or imported without it."""
        try:
            notes = json.loads(self._tables.meta.get(key, "{}"))
        except json.JSONDecodeError:
            return {}
        return notes if isinstance(notes, dict) else {}

    def cells(self) -> list[Cell]:
        """Every stored cell, in k_id order."""
        return sorted((c for cs in self._cells.values() for c in cs.values()),
                      key=lambda c: c.k_id)

    def rows(self, limb: str | None = None, origin: str | None = None,
             direction: str | Direction | None = None) -> list[dict[str, Any]]:
        """Stored rows as plain dicts, optionally filtered (aliases and spellings accepted)."""
        lname = None if limb is None else self._limbs.get(limb) or self._bad_limb(limb)
        oname = None if origin is None else self._origins.get(origin) or self._bad_origin(
            origin, lname or "any limb")
        d = None if direction is None else Direction.parse(direction)
        out = []
        for c in self.cells():
            if (lname or c.limb, oname or c.origin, d or c.direction) != (
                c.limb, c.origin, c.direction
            ):
                continue
            own = self._own.get(c.limb, frozenset())
            for i, s in enumerate(c.sizes):
                cos, reach, margin, *tip = self._quality.get((s, c.k_id), (None,) * 6)
                stored = c.stored[i + 1]
                out.append({"k_id": c.k_id, "p_id": s, "limb": c.limb, "origin": c.origin,
                            "direction": c.direction.slug, "size": s,
                            "joints": {j: v for j, v in stored.items() if j in own},
                            "support": {j: v for j, v in stored.items() if j not in own},
                            "cosine": cos, "reach": reach, "margin": margin,
                            "tip": None if None in tip else tuple(tip)})
        return out

    # -- super-user writes -------------------------------------------------------------------
    def record(self, limb: str, origin: str, direction: str | Direction, size: object,
               joints: Mapping[str, object]) -> Pose:
        """Store a pose for ``(limb, origin, direction, size)`` and serve it at once.

        Limb joints left out keep the stored value of that cell, or neutral for a new cell.
        Everything is validated before the one write transaction, so a bad call changes nothing.
        """
        e = self.platform.eurdf
        lname, oname, d, size_int, given = check_record(
            self.platform, self.vsam, limb, origin, direction, size, joints
        )
        cell = self._cells.get((lname, oname), {}).get(d.slug)
        stored = cell.row(size_int) if cell is not None else None
        base = stored if stored is not None else dict(self._neutral[lname])
        upsert_pose(self.db_path, e.joint_names, (lname, oname, d.slug), size_int, base | given)
        self.reload()
        return self.query(lname, oname, d, size_int)

    def export_json(self, path: str | Path) -> Path:
        """Write the whole databank as JSON (import gives back the same bytes)."""
        return transfer.write_json(path, self._tables)

    def import_json(self, path: str | Path) -> None:
        """Replace this databank atomically with an export (validated first) and reload."""
        write_tables(self.db_path, transfer.tables_from_json(self.platform,
                                                             transfer.read_json(path)))
        self.reload()


_UNITS = {d.slug: d.vector for d in Direction}


def _angle(tip: tuple[float, float, float] | None, slug: str) -> float | None:
    """Degrees between a measured tip offset and a direction (None: unmeasured, or place)."""
    d = _UNITS[slug]
    n = math.sqrt(tip[0] ** 2 + tip[1] ** 2 + tip[2] ** 2) if tip is not None else 0.0
    if tip is None or n < 1e-9 or not any(d):
        return None
    c = (tip[0] * d[0] + tip[1] * d[1] + tip[2] * d[2]) / n
    return round(math.degrees(math.acos(max(-1.0, min(1.0, c)))), 3)


def _rest_tips(meta: Mapping[str, str]) -> dict[str, tuple[float, float, float]]:
    """Where each "limb/origin" points at neutral (``meta.neutral_tips``), for blending."""
    try:
        raw = json.loads(meta.get("neutral_tips", "{}"))
        return {str(k): (float(v[0]), float(v[1]), float(v[2])) for k, v in raw.items()}
    except (ValueError, TypeError, KeyError, IndexError, AttributeError):
        return {}


def _names(parts: Sequence[Any], keep: set[str]) -> dict[str, str]:
    """Label and alias -> label, for the labels in ``keep``."""
    out: dict[str, str] = {}
    for p in parts:
        if p.name in keep:
            out[p.name] = p.name
            if p.alias:
                out[p.alias] = p.name
    return out
