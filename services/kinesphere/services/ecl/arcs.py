"""Geometry of pointing along a direction, for the generator: cosines, arcs, half-way turns.

Vectors are numpy arrays in the body frame; ``d`` is a unit Laban direction vector. Pure
functions, no randomness, fixed iteration counts: the same inputs give the same result.
"""

from __future__ import annotations

import numpy as np

from kinesphere.services.ecl.measure import cosine

__all__ = ["along_arc", "arc_at", "cosine", "halfway"]


def halfway(rest: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The unit direction half-way from the neutral tip direction to d; for opposite
    directions, the way over the top (body up, or forward if the tip rests vertical)."""
    u = rest / max(float(np.linalg.norm(rest)), 1e-9)
    half = u + d
    if float(np.linalg.norm(half)) > 0.2:
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
