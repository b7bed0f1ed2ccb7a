"""The in-memory form of a databank: one :class:`Cell` per stored ``(limb, origin, direction)``.

Built once per load and checked as it is built (a row must set exactly its limb's joints), so
the lookup code can trust it and stay branch-light. Everything the hot path needs is
precomputed here: canonical slugs, unit horizontals, knots with neutral at size 0, and the
stored rows as ready dicts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.platform import Platform
from kinesphere.services.ecl.db import Tables
from kinesphere.services.ecl.store import limb_neutral

Cells = dict[tuple[str, str], dict[str, "Cell"]]
"""(limb, origin) -> direction slug -> cell."""


@dataclass(frozen=True)
class Cell:
    """A stored cell: its sizes and their poses over the limb's joints (none for core cells).

    ``q`` is the numpy matrix (one row per stored size) for bulk users; the hot path uses the
    same numbers as tuples, ``knots``/``values``/``stored``, whose index 0 is size 0 = neutral.
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

    def row(self, size: int) -> dict[str, float] | None:
        """The stored pose of an integer size, or None."""
        return dict(self.stored[self.sizes.index(size) + 1]) if size in self.sizes else None


def unit_horizontal(d: Direction) -> tuple[float, float] | None:
    """The direction's horizontal part as a unit (x, y); None for place (purely vertical)."""
    x, y = d.horizontal.xy
    n = math.hypot(x, y)
    return None if n == 0 else (x / n, y / n)


def build_cells(plat: Platform, t: Tables, source: Path) -> Cells:
    """Group the pose rows by vsam row; rows that break the NULL rule are rejected."""
    e = plat.eurdf
    col = {name: i for i, name in enumerate(t.joints)}
    poses: dict[int, list[tuple[int, tuple[float | None, ...]]]] = {}
    for p_id, k_id, values in t.pose:
        poses.setdefault(k_id, []).append((p_id, values))
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
        q = np.array([[v[col[j]] for j in names] for _, v in rows], dtype=float)
        q = q.reshape(len(rows), len(names))
        neutral = () if core else tuple(limb_neutral(plat, limb).values())
        values_t = (neutral, *(tuple(float(x) for x in r) for r in q))
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
        )
    return cells
