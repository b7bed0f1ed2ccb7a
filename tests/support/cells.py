"""Which Labanotation cells a body can point a part into, from its URDF's joint limits alone.

Whether a score's cell is fair to ask of a body is decided here independently of the
generator (the ECL, its solver, its stored rows): the limb's joints are sampled uniformly
inside their limits (:func:`support.nested.reach`: a fixed seed, configurations where MuJoCo
finds the limb touching anything dropped), each segment's direction is measured by the same
URDF numbers yourdfpy reads, and written as a cell by LabanEditor's own ``coordinate2laban``.

* The outer segment (the upper arm: shoulder to elbow; the head) has a cell when some sample
  points it there. Baxter's upper arm cannot hang straight down (its ``s1`` stops at
  1.047 rad): it has no ``Place Low``.
* The inner segment (the forearm: elbow to the hand) is asked *with* the upper arm's cell
  (nested): it has a cell when some sample points the forearm there with the upper arm in its
  written cell, or, where the body has no such upper-arm cell, with the upper arm within 45°
  of the written direction (the nearest the body can hold it).

The uniform sample is dense enough for the upper arm (it depends on two or three shoulder
joints); a forearm cell reachable only in a sliver of the arm's configuration space may be
missed, which only leaves that cell out of what a test asks.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from types import ModuleType

import numpy as np

from support.nested import SegmentEnds, degrees, reach

SAMPLES = 60000
NEAR = 45.0
"""Degrees: how far off its written direction an upper arm the body cannot put in its cell may
be held for the forearm's cell to be asked of it (the ECL's own bound for another movement)."""


def cell_names(laban_editor: ModuleType, vectors: np.ndarray) -> np.ndarray:
    """Each row's cell as LabanEditor writes it (``"Left Forward High"``), (n,) of str."""
    out = []
    for v in vectors:
        _, theta, phi = laban_editor.to_sphere(v)
        out.append(" ".join(laban_editor.coordinate2laban(theta, phi)))
    return np.array(out)


@dataclass(frozen=True)
class Reachable:
    """The cells one limb's two segments point into over its collision-free samples."""

    outer: np.ndarray
    """(n, 3) unit directions of the outer segment."""
    outer_cells: np.ndarray
    inner_cells: np.ndarray

    def has(self, cell: str) -> bool:
        """Whether the outer segment (upper arm, head) can point into ``cell``."""
        return bool(np.any(self.outer_cells == cell))

    def has_inner(self, outer: str, outer_direction: np.ndarray, inner: str) -> bool:
        """Whether the inner segment (forearm) can point into ``inner`` while the outer is
        in ``outer`` (or, when it cannot be, within :data:`NEAR` of ``outer_direction``)."""
        held = (self.outer_cells == outer if self.has(outer)
                else degrees(self.outer, outer_direction) <= NEAR)
        return bool(np.any(held & (self.inner_cells == inner)))

    def cells(self) -> set[str]:
        return set(self.outer_cells.tolist())


@cache
def reachable(platform: str, limb: str, outer: SegmentEnds, inner: SegmentEnds,
              laban_editor: ModuleType, samples: int = SAMPLES) -> Reachable:
    """What ``limb`` of ``platform`` can point ``outer`` and ``inner`` into (see the module);
    for a limb of one segment (a head) pass it twice."""
    r = reach(platform, limb, (outer, inner), samples=samples)
    return Reachable(r.first, cell_names(laban_editor, r.first),
                     cell_names(laban_editor, r.second))
