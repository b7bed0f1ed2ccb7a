"""The virtual space-access model (k_o, k_d, k_s) of a platform, read from ``vsam.toml``.

The VSAM fixes which ``(limb, origin, direction, size)`` cells an ECL may hold. It is checked
against the platform's labels at load time, so a typo in the file fails with the name and the
valid alternatives instead of producing an ECL with silently missing rows. Mobile platforms
get the derived core entries ``(c_1, c_1, d)`` for the 8 middle horizontals.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kinesphere.errors import KinesphereError, choices
from kinesphere.laban import Direction
from kinesphere.robots.platform import Platform, load_platform
from kinesphere.sizes import DEFAULT_SIZES

LABAN_27 = "laban-27"
LABAN_26 = "laban-26"
_TOP_KEYS = frozenset({"sizes", "directions", "translation_step", "entry"})
_ENTRY_KEYS = frozenset({"limb", "origin", "directions"})


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
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise KinesphereError("malformed", f"{path}: not valid TOML ({exc})") from None
    return vsam_from_dict(data, plat, source=path)


def vsam_from_dict(data: dict[str, Any], plat: Platform, source: str | Path = "vsam") -> Vsam:
    """Validate VSAM data (from TOML or a databank's meta) against the platform's labels."""
    try:
        return _build(data, plat)
    except KinesphereError as exc:
        raise KinesphereError(exc.code, f"{source}: {exc.message}") from None


def _build(data: dict[str, Any], plat: Platform) -> Vsam:
    unknown = sorted(set(data) - _TOP_KEYS)
    if unknown:
        raise KinesphereError(
            "malformed", f"unknown key {unknown[0]!r}; valid keys: {choices(_TOP_KEYS)}"
        )
    sizes = _sizes(data.get("sizes", list(DEFAULT_SIZES)))
    directions = _directions(data.get("directions", LABAN_27), "directions")
    step = _step(data.get("translation_step"), plat)
    raw_entries = data.get("entry", [])
    if not isinstance(raw_entries, list):
        raise KinesphereError("malformed", "'entry' must be an array of tables ([[entry]])")
    entries: list[VsamEntry] = []
    seen: set[tuple[str, str]] = set()
    for i, raw in enumerate(raw_entries, start=1):
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
    return Vsam(plat.name, sizes, directions, step, tuple(entries))


def _sizes(raw: object) -> tuple[int, ...]:
    if not isinstance(raw, list) or not raw:
        raise KinesphereError("size_out_of_range", f"sizes must be a non-empty list, got {raw!r}")
    for s in raw:
        if isinstance(s, bool) or not isinstance(s, int) or s < 1:
            raise KinesphereError(
                "size_out_of_range", f"sizes must be positive integers, got {s!r} in {raw!r}"
            )
    if any(b <= a for a, b in zip(raw, raw[1:], strict=False)):
        raise KinesphereError(
            "size_out_of_range", f"sizes must be strictly increasing, got {raw!r}"
        )
    return tuple(raw)


def _directions(raw: object, where: str) -> tuple[Direction, ...]:
    if raw == LABAN_27:
        return tuple(Direction)
    if raw == LABAN_26:
        return Direction.pulls()
    if not isinstance(raw, list) or not raw:
        raise KinesphereError(
            "malformed",
            f"{where} must be {LABAN_27!r}, {LABAN_26!r} or a non-empty list of names, "
            f"got {raw!r}",
        )
    out: list[Direction] = []
    for name in raw:
        if not isinstance(name, str):
            raise KinesphereError("unknown_direction", f"{where}: {name!r} is not a name")
        d = Direction.parse(name)
        if d in out:
            raise KinesphereError("malformed", f"{where}: direction {d.slug} appears twice")
        out.append(d)
    order = list(Direction)
    return tuple(sorted(out, key=order.index))


def _step(raw: object, plat: Platform) -> float | None:
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
    if isinstance(raw, bool) or not isinstance(raw, (int, float)):
        raise KinesphereError("malformed", f"translation_step must be a number, got {raw!r}")
    if not math.isfinite(raw) or raw <= 0:
        raise KinesphereError("malformed", f"translation_step must be > 0 metres, got {raw!r}")
    return float(raw)


def _entry(raw: object, i: int, plat: Platform, k_d: tuple[Direction, ...]) -> VsamEntry:
    if not isinstance(raw, dict):
        raise KinesphereError("malformed", f"entry {i} must be a table with limb and origin")
    unknown = sorted(set(raw) - _ENTRY_KEYS)
    if unknown:
        raise KinesphereError(
            "malformed", f"entry {i}: unknown key {unknown[0]!r}; valid: {choices(_ENTRY_KEYS)}"
        )
    for key in ("limb", "origin"):
        if not isinstance(raw.get(key), str):
            raise KinesphereError("malformed", f"entry {i}: {key} must be a label name")
    e = plat.eurdf
    try:
        limb = e.limb(raw["limb"]).name
        origin = e.origin(raw["origin"])
    except KinesphereError as exc:
        raise KinesphereError(exc.code, f"entry {i}: {exc.message}") from None
    if origin.set != "J":
        raise KinesphereError(
            "unknown_origin",
            f"entry {i}: origin {raw['origin']!r} is a core label; origins are joint locations "
            f"(k_o = J): {', '.join(e.J)}",
        )
    directions = k_d
    if "directions" in raw:
        directions = _directions(raw["directions"], f"entry {i} directions")
        outside = [d.slug for d in directions if d not in k_d]
        if outside:
            raise KinesphereError(
                "unknown_direction",
                f"entry {i}: {outside[0]} is not among the VSAM's directions (k_d)",
            )
    return VsamEntry(limb, origin.name, directions)
