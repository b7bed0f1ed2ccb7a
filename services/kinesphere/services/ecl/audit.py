"""``ecl audit``: what a databank's words mean on its body, measured by forward kinematics.

Every figure is measured from the stored joint values alone (:mod:`measure`: MuJoCo on the
platform's model), never from the generator's own bookkeeping (the quality table), so the next
change to the generator shows its effect in numbers. Per (limb, origin) pair:

* **pointing**: the cosine between each stored row's bearing (tip - origin) and its direction,
  min / 5th percentile / median over every stored size;
* **reach**: each size's tip distance from the origin as a fraction of the far tip's (median
  over the cells that store far), and the cells whose sizes go backwards (the tip closer as
  the size grows; for a limb that swings, its bearing turning away from the direction);
* **sizes**: cells that stop short of the largest size (removed for stability);
* **substitution**: every pull the pair does not store, asked at every size as a fleet command
  (not exact), and the measured angle between the request and where the served pose points;
* **neutral directions**: the pulls the neutral pose already points at (cosine >= HONEST) and
  how the databank answers them: stored, served by a neighbour, or refused;
* **stability**: the centre of mass's margin inside the support polygon for every stored row
  (a fixed base cannot topple: no figure).
"""

from __future__ import annotations

import json
import statistics
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.mjcf import model_of
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.measure import Fk, angle_deg, cosine
from kinesphere.substitution import MAX_ANGLE_DEG

STABLE = 0.01
"""metres: the margin a stored row keeps inside the support polygon to count as stable."""
ROUNDING = 0.01
"""degrees: stored joint values and tips are rounded to 1e-6, so a substitution the databank
served at exactly 45 degrees measures a hair over; this much is not counted against it."""


@dataclass(frozen=True)
class Served:
    """How one request the pair does not store is answered, at one size."""

    direction: str
    size: int
    served: str | None  # the direction served, None when refused
    angle: float | None  # degrees between the request and the served pose's bearing
    code: str | None = None  # the refusal's code


@dataclass
class PairAudit:
    """The measured figures of one (limb, origin) pair."""

    limb: str
    origin: str
    alias: str
    rule: str  # the generator's size rule from the databank ("reach", "swing") or "-"
    pulls: int  # pulls of Laban's 26 stored
    rows: int
    cosine_min: float | None
    cosine_p5: float | None
    cosine_median: float | None
    fraction: dict[int, float]  # size -> median tip distance / far tip distance
    disordered: list[str]  # cells whose sizes go backwards (see _disordered)
    short: dict[str, list[int]]  # cells stopping short of the largest size: their sizes
    substituted: list[Served]  # requests served by another direction (every size)
    refused: list[Served]
    neutral: dict[str, str]  # neutral direction -> "stored" / "neighbour X (a deg)" / "refused"
    margin_min: float | None  # metres; None on a fixed base
    unstable: list[str] = field(default_factory=list)  # rows under STABLE, "direction size"

    @property
    def worst_substitution(self) -> float | None:
        angles = [s.angle for s in self.substituted if s.angle is not None]
        return max(angles) if angles else None


@dataclass
class Audit:
    """One databank's audit: its pairs, in VSAM order."""

    platform: str
    version: str
    generator: str
    anchored: bool
    pairs: list[PairAudit]

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, sort_keys=False)


def audit(platform: str | Path, db: str | Path | None = None) -> Audit:
    """Measure a databank (the platform's shipped or own one, or ``db``)."""
    ecl = Ecl.open(platform, db=db)
    fk = Fk(model_of(ecl.platform))
    rules = ecl.notes("size_rules")
    aliases = {p.name: p.alias or "" for p in ecl.platform.eurdf.limbs}
    pairs = [
        _pair(ecl, fk, e.limb, e.origin, aliases.get(e.limb, ""),
              str(rules.get(f"{e.limb}/{e.origin}", "-")))
        for e in ecl.vsam.entries if not e.is_core
    ]
    return Audit(ecl.platform.name, ecl.version, ecl.meta.get("generator_version", ""),
                 fk.anchored, pairs)


def _pair(ecl: Ecl, fk: Fk, limb: str, origin: str, alias: str, rule: str) -> PairAudit:
    sizes = ecl.vsam.sizes
    largest = max(sizes)
    rows = [r for r in ecl.rows(limb, origin) if r["direction"] != "place-middle"]
    cells: dict[str, dict[int, np.ndarray]] = {}
    cosines: list[float] = []
    margins: list[tuple[float, str]] = []
    for r in rows:
        joints = r["joints"] | r.get("support", {})
        offset = fk.offset(limb, origin, joints)
        cells.setdefault(r["direction"], {})[r["size"]] = offset
        cosines.append(cosine(offset, np.array(Direction.parse(r["direction"]).vector)))
        margin = fk.com_margin(joints)
        if margin is not None:
            margins.append((margin, f"{r['direction']} {r['size']}"))
    fraction: dict[int, float] = {}
    for s in sizes:
        ratios = [float(np.linalg.norm(c[s]) / np.linalg.norm(c[largest]))
                  for c in cells.values() if s in c and largest in c
                  and np.linalg.norm(c[largest]) > 1e-9]
        if ratios:
            fraction[s] = statistics.median(ratios)
    swung = set(ecl.notes("swung").get(f"{limb}/{origin}", []))
    disordered = sorted(d for d, c in cells.items()
                        if _disordered(c, Direction.parse(d), rule == "swing" or d in swung))
    short = {d: sorted(c) for d, c in cells.items() if largest not in c}
    substituted, refused = _requests(ecl, fk, limb, origin, set(cells))
    neutral = {}
    for d in fk.neutral_directions(limb, origin):
        if d.slug in cells:
            neutral[d.slug] = "stored"
            continue
        mine = [s for s in substituted + refused if s.direction == d.slug]
        worst = max(mine, key=lambda s: (s.served is None, s.angle or 0.0))
        neutral[d.slug] = ("refused" if worst.served is None
                           else f"neighbour {worst.served} ({worst.angle:.0f} deg)")
    qs = sorted(cosines)
    return PairAudit(
        limb=limb, origin=origin, alias=alias, rule=rule, pulls=len(cells), rows=len(rows),
        cosine_min=qs[0] if qs else None,
        cosine_p5=float(np.percentile(qs, 5)) if qs else None,
        cosine_median=statistics.median(qs) if qs else None,
        fraction=fraction, disordered=disordered, short=short, substituted=substituted,
        refused=refused, neutral=neutral,
        margin_min=min(m for m, _ in margins) if margins else None,
        unstable=[where for m, where in margins if m < STABLE],
    )


def _disordered(cell: dict[int, np.ndarray], d: Direction, swing: bool) -> bool:
    """Whether a bigger size of a cell reaches less: its tip closer to the origin (by more
    than a millimetre), or, for a limb that swings, its bearing turned away from d."""
    sizes = sorted(cell)
    def grows(x: np.ndarray) -> float:
        return cosine(x, np.array(d.vector)) if swing else float(np.linalg.norm(x))
    slack = 1e-3
    return any(grows(cell[b]) < grows(cell[a]) - slack
               for a, b in zip(sizes, sizes[1:], strict=False))


def _requests(ecl: Ecl, fk: Fk, limb: str, origin: str, stored: set[str]
              ) -> tuple[list[Served], list[Served]]:
    """Every pull the pair lacks, asked at every size as a fleet command: what is served and
    where it points (measured), or the refusal."""
    substituted: list[Served] = []
    refused: list[Served] = []
    for d in Direction.pulls():
        if d.slug in stored:
            continue
        for s in ecl.vsam.sizes:
            try:
                pose = ecl.query(limb, origin, d, s)
            except KinesphereError as exc:
                refused.append(Served(d.slug, s, None, None, exc.code))
                continue
            offset = fk.offset(limb, origin, pose.joints)
            substituted.append(Served(d.slug, s, pose.direction,
                                      angle_deg(offset, np.array(d.vector))))
    return substituted, refused


def over_limit(pair: PairAudit) -> list[Served]:
    """Substitutions pointing more than MAX_ANGLE_DEG away from the request (measured)."""
    return [s for s in pair.substituted
            if s.angle is not None and s.angle > MAX_ANGLE_DEG + ROUNDING]
