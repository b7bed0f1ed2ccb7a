"""Kinesphere sizes: near/mid/far reach as integers, and "beyond" as base translation.

A VSAM stores integer sizes ``1..k_smax``. Users may ask for any finite size >= 0: fractions
between stored sizes interpolate, sizes above ``k_smax`` keep the far pose and translate the
base by the excess (``(s - k_smax) * step`` metres) when the platform can move.
"""

from __future__ import annotations

import math
from typing import Final

from kinesphere.errors import KinesphereError

NEAR: Final = 1
MID: Final = 2
FAR: Final = 3
"""The stored sizes by name: near, mid and far reach (far is ``k_smax`` of a default VSAM)."""
NAMED_SIZES: dict[str, int] = {"near": NEAR, "mid": MID, "middle": MID, "far": FAR}
DEFAULT_SIZES: tuple[int, ...] = (NEAR, MID, FAR)
MAX_TRANSLATION = 10.0
"""Metres: the largest base translation one answer (or compound) may carry, whatever the size."""
DEFAULT_BEYOND = 20
"""Size units past the largest stored size a mobile platform answers unless its VSAM says."""


def parse_size(value: object) -> float:
    """Turn ``3``, ``"2.5"``, ``"far"`` into a finite non-negative float, or explain why not."""
    if isinstance(value, bool):
        raise KinesphereError("size_out_of_range", f"size must be a number, got {value!r}")
    if isinstance(value, str):
        named = NAMED_SIZES.get(value.strip().lower())
        if named is not None:
            return float(named)
        try:
            number = float(value)
        except ValueError:
            raise KinesphereError(
                "size_out_of_range",
                f"size {value!r} is not a number or one of near, mid, far",
            ) from None
    elif isinstance(value, (int, float)):
        number = float(value)
    else:
        raise KinesphereError(
            "size_out_of_range", f"size must be a number, got {type(value).__name__}"
        )
    if not math.isfinite(number) or number < 0:
        raise KinesphereError("size_out_of_range", f"size must be finite and >= 0, got {value!r}")
    return number


def size_name(size: float) -> str:
    """Human name of a size: near, mid, far, beyond(+x) or the number itself."""
    names: dict[float, str] = {NEAR: "near", MID: "mid", FAR: "far"}
    if size in names:
        return names[size]
    if size > FAR:
        return f"beyond (+{size - FAR:g})"
    return f"{size:g}"
