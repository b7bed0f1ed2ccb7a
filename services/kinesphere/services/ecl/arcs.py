"""Geometry of pointing along a direction, for the generator and the nested solver: cosines,
arcs, half-way turns, and the one size rule of a part that swings (:func:`swing`).

Vectors are numpy arrays in the body frame; ``d`` is a unit Laban direction vector. Pure
functions, no randomness, fixed iteration counts: the same inputs give the same result.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from kinesphere.services.ecl.measure import cosine

__all__ = ["Swing", "along_arc", "arc_at", "cosine", "halfway", "swing"]

OPPOSITE = 0.2
"""Two unit directions whose sum is this short (more than ~168 degrees apart) are opposite:
the way from one to the other goes over the top."""


def halfway(rest: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The unit direction half-way from the neutral tip direction to d; for opposite
    directions, the way over the top (body up, or forward if the tip rests vertical)."""
    u = rest / max(float(np.linalg.norm(rest)), 1e-9)
    half = u + d
    if float(np.linalg.norm(half)) > OPPOSITE:
        return np.asarray(half / np.linalg.norm(half))
    up = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    side = up - (up @ u) * u
    return np.asarray(side / np.linalg.norm(side))


def along_arc(start: np.ndarray, end: np.ndarray, g: float) -> np.ndarray:
    """Fraction ``g`` of the way from ``start`` to ``end``: slerp of direction, lerp of length."""
    la, lb = float(np.linalg.norm(start)), float(np.linalg.norm(end))
    a, b = start / la, end / lb
    angle = float(np.arccos(np.clip(a @ b, -1.0, 1.0)))
    if angle < 1e-6:
        return np.asarray(b * ((1 - g) * la + g * lb))
    u = (np.sin((1 - g) * angle) * a + np.sin(g * angle) * b) / np.sin(angle)
    return np.asarray(u * ((1 - g) * la + g * lb))


def arc_at(start: np.ndarray, end: np.ndarray, d: np.ndarray, proj: float) -> np.ndarray:
    """The first point on the arc from ``start`` to ``end`` whose projection on d reaches
    ``proj`` (a coarse scan, then bisection: deterministic)."""
    grid = np.linspace(0.0, 1.0, 65)
    above = [float(g) for g in grid if float(along_arc(start, end, float(g)) @ d) >= proj]
    hi = above[0] if above else 1.0
    lo = max(hi - 1.0 / 64, 0.0)
    for _ in range(30):
        mid = (lo + hi) / 2
        if float(along_arc(start, end, mid) @ d) < proj:
            lo = mid
        else:
            hi = mid
    return along_arc(start, end, hi)


class Swing(NamedTuple):
    """Where a part that swings points at one size: ``share`` of the turn from its rest
    bearing toward far's (0 at rest, 1 at far), and the ``offset`` it points along."""

    share: float
    offset: np.ndarray


def swing(rest: np.ndarray, far: np.ndarray, size: float, sizes: Sequence[float],
          at_rest: bool) -> Swing:
    """The size rule of a part whose length cannot change (a head, a wrist, a nested segment):
    the size scales the *angle* of the pull. At ``size`` the bearing has turned ``size /
    k_smax`` of the way from ``rest`` (where it points at neutral) toward ``far`` (where it
    points at the largest size, ``sizes[-1]``), along the great circle through their half-way
    direction (over the top when they are opposite, :func:`halfway`), its length lerped; at
    far and beyond, ``far`` itself. A part that already points the way asked at rest
    (``at_rest``: :func:`~kinesphere.services.ecl.measure.points_along`) is answered by rest at
    the smallest size and the sizes above share the turn: ``(size - near) / (k_smax - near)``.

    The generator's stored swing sizes (``far`` the far pose's measured offset) and the
    nested solver's segments (``far`` the direction asked) both follow this one rule.
    """
    near, k_smax = float(sizes[0]), float(sizes[-1])
    lr, lf = float(np.linalg.norm(rest)), float(np.linalg.norm(far))
    a, b = rest / max(lr, 1e-9), far / max(lf, 1e-9)
    if at_rest and k_smax > near:
        g = (size - near) / (k_smax - near)
    else:
        g = size / k_smax
    g = min(max(g, 0.0), 1.0)
    if float(np.linalg.norm(a + b)) > OPPOSITE:  # the arc through the half-way direction
        return Swing(g, along_arc(rest, far, g))
    mid = halfway(a, b)  # over the top
    u = along_arc(a, mid, 2 * g) if g <= 0.5 else along_arc(mid, b, 2 * g - 1)
    return Swing(g, np.asarray(u / np.linalg.norm(u) * ((1 - g) * lr + g * lf)))
