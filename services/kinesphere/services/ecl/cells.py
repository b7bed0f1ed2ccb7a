"""The in-memory form of a databank: one :class:`Cell` per stored ``(limb, origin, direction)``.

Built once per load and checked as it is built (a row must set exactly its limb's joints), so
the lookup code can trust it and stay branch-light. Everything the hot path needs is
precomputed here: canonical slugs, unit horizontals, knots with neutral at size 0, and the
stored rows as ready dicts.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.platform import Platform
from kinesphere.services.ecl.db import Tables

Cells = dict[tuple[str, str], dict[str, "Cell"]]
"""(limb, origin) -> direction slug -> cell."""


@dataclass(frozen=True)
class Cell:
    """A stored cell: its sizes and their poses over the limb's joints (none for core cells).

    ``q`` is the numpy matrix (one row per stored size) for bulk users; the hot path uses the
    same numbers as tuples, ``knots``/``values``/``stored``, whose index 0 is size 0 = neutral.
    ``joints`` are the limb's, then those of its support (a stance leg), if any. ``tips`` is
    where the limb's tip is at each knot (tip - origin, body frame, measured when the databank
    was built; None where unknown).
    """

    k_id: int
    limb: str
    origin: str
    direction: Direction
    slug: str
    horizontal: tuple[float, float] | None
    joints: tuple[str, ...]
    sizes: tuple[int, ...]
    q: np.ndarray
    knots: tuple[float, ...]
    values: tuple[tuple[float, ...], ...]
    stored: tuple[dict[str, float], ...]
    tips: tuple[tuple[float, float, float] | None, ...] = ()

    def tip_at(self, s: float) -> tuple[float, float, float] | None:
        """Where the tip is at size ``s``: measured at a stored size, blended between two
        (as f_SB blends the joints), far's past the largest; None where unknown."""
        if not self.tips:
            return None
        i = bisect.bisect_right(self.knots, s) - 1
        if i >= len(self.knots) - 1 or s == self.knots[i]:
            return self.tips[min(i, len(self.tips) - 1)]
        a, b = self.tips[i], self.tips[i + 1]
        if a is None or b is None:
            return None
        t = (s - self.knots[i]) / (self.knots[i + 1] - self.knots[i])
        return (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2]))

    def row(self, size: int) -> dict[str, float] | None:
        """The stored pose of an integer size, or None."""
        return dict(self.stored[self.sizes.index(size) + 1]) if size in self.sizes else None


def unit_horizontal(d: Direction) -> tuple[float, float] | None:
    """The direction's horizontal part as a unit (x, y); None for place (purely vertical)."""
    x, y = d.horizontal.xy
    n = math.hypot(x, y)
    return None if n == 0 else (x / n, y / n)


def build_cells(plat: Platform, t: Tables, source: Path,
                rests: dict[str, tuple[float, float, float]] | None = None) -> Cells:
    """Group the pose rows by vsam row (with their support and measured tips); rows that break
    the NULL rule are rejected. ``rests``: where each "limb/origin" points at neutral."""
    e = plat.eurdf
    col = {name: i for i, name in enumerate(t.joints)}
    poses: dict[int, list[tuple[int, tuple[float | None, ...]]]] = {}
    for p_id, k_id, values in t.pose:
        poses.setdefault(k_id, []).append((p_id, values))
    support = {(p, k): values for p, k, values in t.support}
    tips: dict[tuple[int, int], tuple[float, float, float]] = {}
    for p, k, _, _, _, x, y, z in t.quality:
        if x is not None and y is not None and z is not None:
            tips[(p, k)] = (x, y, z)
    cells: Cells = {}
    for k_id, origin, limb, slug in t.vsam:
        rows = sorted(poses.get(k_id, []))
        if not rows:
            continue
        d = Direction.parse(slug)
        core = limb in e.C
        names = () if core else e.limb_joints(limb)
        for p_id, values in rows:
            inside = [values[col[j]] for j in names]
            outside = [v for j, v in zip(t.joints, values, strict=True) if j not in names]
            if None in inside or any(v is not None for v in outside):
                raise KinesphereError(
                    "malformed",
                    f"{source}: pose ({p_id}, {k_id}) of {limb} must set exactly its joints",
                )
        sizes = tuple(p for p, _ in rows)
        held = [support.get((p_id, k_id)) for p_id, _ in rows]
        extra = tuple(j for j in t.joints
                      if any(h is not None and h[col[j]] is not None for h in held))
        names = (*names, *extra)
        rest = {j: plat.neutral.get(j, 0.0) for j in names}
        q = np.array([[_value(v, h, col[j], rest[j]) for j in names]
                      for (_, v), h in zip(rows, held, strict=True)], dtype=float)
        q = q.reshape(len(rows), len(names))
        neutral = () if core else tuple(rest[j] for j in names)
        values_t = (neutral, *(tuple(float(x) for x in r) for r in q))
        rest_tip = (rests or {}).get(f"{limb}/{origin}")
        cells.setdefault((limb, origin), {})[d.slug] = Cell(
            k_id=k_id,
            limb=limb,
            origin=origin,
            direction=d,
            slug=d.slug,
            horizontal=unit_horizontal(d),
            joints=names,
            sizes=sizes,
            q=q,
            knots=(0.0, *map(float, sizes)),
            values=values_t,
            stored=tuple(dict(zip(names, r, strict=True)) for r in values_t),
            tips=(rest_tip, *(tips.get((p_id, k_id)) for p_id, _ in rows)),
        )
    return cells


def _value(pose: tuple[float | None, ...], support: tuple[float | None, ...] | None, i: int,
           rest: float) -> float:
    """A joint's value in a stored row: the pose's, else its support's, else neutral."""
    v = pose[i]
    if v is None and support is not None:
        v = support[i]
    return rest if v is None else float(v)
