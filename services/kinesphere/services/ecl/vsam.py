"""The virtual space-access model (k_o, k_d, k_s) of a platform, read from ``vsam.toml``.

The VSAM fixes which ``(limb, origin, direction, size)`` cells an ECL may hold. It is checked
against the platform's labels at load time, so a typo in the file fails with the name and the
valid alternatives instead of producing an ECL with silently missing rows. Mobile platforms
get the derived core entries ``(c_1, c_1, d)`` for the 8 middle horizontals. ``max_size`` is
the largest size the ECL answers: the largest stored size on a fixed base, and on a mobile one
what the file says (default DEFAULT_BEYOND units past it), never more than MAX_TRANSLATION
metres of base translation.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Final, Literal

import msgspec

from kinesphere.configfile import convert, read_toml
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.platform import Platform, load_platform
from kinesphere.sizes import DEFAULT_BEYOND, DEFAULT_SIZES, MAX_TRANSLATION

LABAN_27: Final = "laban-27"
LABAN_26: Final = "laban-26"
_DirectionSpec = (
    Literal["laban-27", "laban-26"]
    | Annotated[list[str], msgspec.Meta(min_length=1, max_length=len(Direction))]
)
_Sizes = Annotated[
    list[Annotated[int, msgspec.Meta(ge=1, le=64, description="a positive integer")]],
    msgspec.Meta(min_length=1, max_length=64, description="a non-empty list of positive integers",
                 extra={"code": "size_out_of_range"}),
]
_Step = Annotated[
    float, msgspec.Meta(gt=0, le=100, description="> 0 metres (per size unit past the largest)")
]
_MaxSize = Annotated[float, msgspec.Meta(ge=1, le=1e6, description="the largest size answered")]


class _EntryTable(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    limb: str
    origin: str
    directions: _DirectionSpec | None = None


class _VsamFile(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """vsam.toml as written (or a databank's copy in its meta table)."""

    sizes: _Sizes = msgspec.field(default_factory=lambda: list(DEFAULT_SIZES))
    directions: _DirectionSpec = LABAN_27
    translation_step: _Step | None = None
    max_size: _MaxSize | None = None
    entry: list[_EntryTable] = []

    def __post_init__(self) -> None:
        if any(b <= a for a, b in zip(self.sizes, self.sizes[1:], strict=False)):
            raise KinesphereError(
                "size_out_of_range", f"sizes must be strictly increasing, got {self.sizes!r}"
            )


@dataclass(frozen=True)
class VsamEntry:
    """One ``(limb, origin)`` pair and the directions it may be pulled in (canonical names)."""

    limb: str
    origin: str
    directions: tuple[Direction, ...]

    @property
    def is_core(self) -> bool:
        """Core entries translate the base; they have no joints."""
        return self.limb.startswith("c_")


@dataclass(frozen=True)
class Vsam:
    """A platform's VSAM; ``entries`` ends with the derived core entries on mobile platforms."""

    platform: str
    sizes: tuple[int, ...]
    directions: tuple[Direction, ...]
    translation_step: float | None
    entries: tuple[VsamEntry, ...]
    max_size: float = 0.0
    """The largest size answered (``size_out_of_range`` past it); see the module."""

    @property
    def k_smax(self) -> int:
        return self.sizes[-1]

    @property
    def origins(self) -> tuple[str, ...]:
        """k_o: every origin used by an entry, in entry order."""
        return tuple(dict.fromkeys(e.origin for e in self.entries))

    @property
    def can_translate(self) -> bool:
        return self.translation_step is not None

    def entry(self, limb: str, origin: str) -> VsamEntry | None:
        for e in self.entries:
            if e.limb == limb and e.origin == origin:
                return e
        return None

    def to_dict(self) -> dict[str, Any]:
        """The file-level content (core entries are derived again on load)."""
        return {
            "sizes": list(self.sizes),
            "directions": [d.slug for d in self.directions],
            "translation_step": self.translation_step,
            "max_size": self.max_size,
            "entry": [
                {"limb": e.limb, "origin": e.origin, "directions": [d.slug for d in e.directions]}
                for e in self.entries
                if not e.is_core
            ],
        }

    def to_json(self) -> str:
        """Canonical JSON, stored in the databank's ``meta`` table."""
        return json.dumps(self.to_dict(), sort_keys=True, separators=(",", ":"))


def load_vsam(platform: Platform | str) -> Vsam:
    """Read and validate ``vsam.toml`` of a platform (a Platform, a name or a folder)."""
    plat = platform if isinstance(platform, Platform) else load_platform(platform)
    path = plat.vsam_path
    if not path.is_file():
        raise KinesphereError("unavailable", f"{plat.name} has no VSAM file: {path} is missing")
    return vsam_from_dict(read_toml(path, "VSAM file"), plat, source=path)


def vsam_from_dict(data: dict[str, Any], plat: Platform, source: str | Path = "vsam") -> Vsam:
    """Validate VSAM data (from TOML or a databank's meta) against the platform's labels."""
    f = convert(data, _VsamFile, str(source))
    try:
        return _build(f, plat)
    except KinesphereError as exc:
        raise KinesphereError(exc.code, f"{source}: {exc.message}") from None


def _build(f: _VsamFile, plat: Platform) -> Vsam:
    directions = _directions(f.directions, "directions")
    step = _step(f.translation_step, plat)
    entries: list[VsamEntry] = []
    seen: set[tuple[str, str]] = set()
    for i, raw in enumerate(f.entry, start=1):
        entry = _entry(raw, i, plat, directions)
        if (entry.limb, entry.origin) in seen:
            raise KinesphereError(
                "malformed", f"entry {i}: pair ({entry.limb}, {entry.origin}) appears twice"
            )
        seen.add((entry.limb, entry.origin))
        entries.append(entry)
    if plat.base.mobile:
        core = plat.eurdf.C[0]
        entries.append(VsamEntry(core, core, Direction.translations()))
    if not entries:
        raise KinesphereError(
            "malformed", f"no [[entry]]: a fixed-base platform needs at least one (limb, origin) "
            f"pair; limbs: {', '.join(plat.eurdf.L) or 'none'}"
        )
    max_size = _max_size(f.max_size, f.sizes[-1], step)
    return Vsam(plat.name, tuple(f.sizes), directions, step, tuple(entries), max_size)


def _max_size(raw: float | None, k_smax: int, step: float | None) -> float:
    if step is None:
        if raw is not None and raw != k_smax:
            raise KinesphereError(
                "malformed", f"a fixed base answers sizes up to {k_smax} (far); max_size must be "
                f"{k_smax} or left out, got {raw!r}",
            )
        return float(k_smax)
    if raw is None:
        raw = k_smax + min(DEFAULT_BEYOND, MAX_TRANSLATION / step)
    most = k_smax + MAX_TRANSLATION / step
    if not k_smax <= raw <= most:
        raise KinesphereError(
            "malformed", f"max_size must lie between the largest size {k_smax} and {most:g} "
            f"({MAX_TRANSLATION:g} m of translation at {step:g} m per size), got {raw!r}",
        )
    return float(raw)


def _directions(raw: str | list[str], where: str) -> tuple[Direction, ...]:
    if raw == LABAN_27:
        return tuple(Direction)
    if raw == LABAN_26:
        return Direction.pulls()
    out: list[Direction] = []
    for name in raw:
        d = Direction.parse(name)
        if d in out:
            raise KinesphereError("malformed", f"{where}: direction {d.slug} appears twice")
        out.append(d)
    order = list(Direction)
    return tuple(sorted(out, key=order.index))


def _step(raw: float | None, plat: Platform) -> float | None:
    if not plat.base.mobile:
        if raw is not None:
            raise KinesphereError(
                "malformed",
                f"{plat.name} has a fixed base ({plat.base.kind}); remove translation_step",
            )
        return None
    if raw is None:
        raise KinesphereError(
            "malformed",
            f"{plat.name} has a mobile base ({plat.base.kind}); translation_step "
            "(metres per size unit beyond the largest size) is required",
        )
    return raw


def _entry(raw: _EntryTable, i: int, plat: Platform, k_d: tuple[Direction, ...]) -> VsamEntry:
    e = plat.eurdf
    try:
        limb = e.limb(raw.limb).name
        origin = e.origin(raw.origin)
    except KinesphereError as exc:
        raise KinesphereError(exc.code, f"entry {i}: {exc.message}") from None
    if origin.set != "J":
        raise KinesphereError(
            "unknown_origin",
            f"entry {i}: origin {raw.origin!r} is a core label; origins are joint locations "
            f"(k_o = J): {', '.join(e.J)}",
        )
    directions = k_d
    if raw.directions is not None:
        directions = _directions(raw.directions, f"entry {i} directions")
        outside = [d.slug for d in directions if d not in k_d]
        if outside:
            raise KinesphereError(
                "unknown_direction",
                f"entry {i}: {outside[0]} is not among the VSAM's directions (k_d)",
            )
    return VsamEntry(limb, origin.name, directions)
