"""How much of Laban's vocabulary each body answers, and what a fleet command can count on.

The paper's promise is one command for every body; what each body honestly keeps differs.
This module counts, from the shipped databanks, the pulls (of Laban's 26) each (limb, origin)
pair keeps and the directions that every body with a given limb label shares: a fleet
command in a shared direction is exact on every robot, any other is substituted on some
(``fallback``). ``kinesphere ecl coverage`` prints the tables docs/ecl.md shows.
"""

from __future__ import annotations

from dataclasses import dataclass

from kinesphere.laban import Direction
from kinesphere.services.ecl.ecl import Ecl

PULLS = len(Direction.pulls())


@dataclass(frozen=True)
class Kept:
    """One (limb, origin) pair of one platform: its alias and the pulls it keeps."""

    platform: str
    limb: str
    origin: str
    alias: str
    pulls: tuple[Direction, ...]
    unstable: int  # pulls dropped for stability (even near would topple)
    rule: str = "-"  # the size rule: "reach" or "swing"
    short: int = 0  # kept pulls whose largest sizes stability removed


def kept(platforms: list[str]) -> list[Kept]:
    """Every (limb, origin) pair of the platforms' shipped databanks, in catalogue order."""
    out: list[Kept] = []
    for name in platforms:
        ecl = Ecl.open(name)
        aliases = {p.name: p.alias or "" for p in ecl.platform.eurdf.limbs}
        unstable, short = ecl.dropped("unstable"), ecl.dropped("short")
        rules = ecl.notes("size_rules")
        for entry in ecl.catalogue().limbs:
            have = {Direction.parse(d) for d in entry.directions}
            pulls = tuple(d for d in Direction.pulls() if d in have)
            pair = f"{entry.limb}/{entry.origin}"
            out.append(Kept(name, entry.limb, entry.origin, aliases.get(entry.limb, ""), pulls,
                            len(unstable.get(pair, {})), str(rules.get(pair, "-")),
                            len(short.get(pair, {}))))
    return out


def shared(rows: list[Kept], limb: str) -> tuple[Direction, ...]:
    """The pulls every platform with ``limb`` keeps for it (from its own joint location)."""
    sets = [set(r.pulls) for r in rows if r.limb == limb]
    common = set.intersection(*sets) if sets else set()
    return tuple(d for d in Direction.pulls() if d in common)


def markdown(platforms: list[str], limbs: tuple[str, ...] = ("limb_11", "limb_12", "limb_13")
             ) -> str:
    """docs/ecl.md's two coverage tables (per pair, then shared per limb label)."""
    rows = kept(platforms)
    lines = ["| platform | limb (alias) | origin | size rule | pulls kept of 26 | top sizes "
             "removed for stability | dropped for stability |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        alias = f" ({r.alias})" if r.alias else ""
        lines.append(f"| {r.platform} | {r.limb}{alias} | {r.origin} | {r.rule} | "
                     f"{len(r.pulls)} | {r.short} | {r.unstable} |")
    lines += ["", "| limb | bodies | directions every body keeps |", "|---|---|---|"]
    for limb in limbs:
        bodies = [r.platform for r in rows if r.limb == limb]
        common = shared(rows, limb)
        names = ", ".join(d.slug for d in common) or "none"
        lines.append(f"| {limb} | {', '.join(bodies)} | {len(common)}: {names} |")
    return "\n".join(lines) + "\n"
