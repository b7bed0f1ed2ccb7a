"""Dotted names the docs write (``kinesphere.laban.Direction.parse``) resolved in the tree."""

from __future__ import annotations

import importlib

MISSING = object()
"""What :func:`resolve` gives for a name that names nothing."""


def resolve(dotted: str) -> object:
    """The object ``dotted`` names: its longest importable module prefix, then attributes;
    :data:`MISSING` where the prefix lacks one (or no prefix imports)."""
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj: object = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError:
            continue
        for attr in parts[cut:]:
            obj = getattr(obj, attr, MISSING)
            if obj is MISSING:
                break
        return obj
    return MISSING
