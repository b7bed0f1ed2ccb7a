"""One error type for everything a user or a peer can get wrong.

Each error carries a stable ``code`` (machines branch on it, it travels in protocol ``Error``
replies) and a ``message`` for people that says what was wrong and what would be valid.
"""

from __future__ import annotations

from collections.abc import Iterable

ERROR_CODES: frozenset[str] = frozenset(
    {
        "unknown_platform",
        "unknown_limb",
        "unknown_origin",
        "unknown_direction",
        "direction_unavailable",
        "size_out_of_range",
        "cannot_translate",
        "malformed",
        "forbidden",
        "conflict",
        "incompatible_version",
        "unavailable",
        "invalid_eurdf",
        "lease_held",
        "estopped",
        "stale",
        "expired",
        "internal",
    }
)


class KinesphereError(Exception):
    """An error with a stable code and a human message."""

    def __init__(self, code: str, message: str) -> None:
        if code not in ERROR_CODES:
            raise ValueError(f"unknown error code {code!r}")
        super().__init__(f"{code}: {message}")
        self.code = code
        self.message = message


def choices(values: Iterable[object]) -> str:
    """Format valid alternatives for an error message, sorted and comma separated."""
    return ", ".join(sorted(str(v) for v in values))
