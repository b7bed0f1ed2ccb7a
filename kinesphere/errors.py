"""One error type for everything a user or a peer can get wrong.

Each error carries a stable ``code`` (machines branch on it, it travels in protocol ``Error``
replies) and a ``message`` for people that says what was wrong and what would be valid.
"""

from __future__ import annotations

import difflib
import functools
from collections.abc import Iterable

ERROR_CODES: frozenset[str] = frozenset(
    {
        "unknown_platform",
        "unknown_limb",
        "unknown_origin",
        "absent_part",
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
        "not_found",
        "id_taken",
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

    def __reduce__(self) -> tuple[type[KinesphereError], tuple[str, str]]:
        """Pickle by code and message, so the error crosses process boundaries intact."""
        return (type(self), (self.code, self.message))


def choices(values: Iterable[object]) -> str:
    """Format valid alternatives for an error message, sorted and comma separated."""
    return ", ".join(sorted(str(v) for v in values))


def did_you_mean(word: object, valid: Iterable[str]) -> str:
    """``" (did you mean 'right_arm'?)"`` for the valid name nearest a mistyped one, else "".

    Matching ignores case; the suggestion is spelled as the valid name is. Peers can send any
    name, so the search is bounded: names far longer than every valid one get no suggestion,
    and the answers for the last :data:`SUGGESTIONS_CACHED` mistakes are kept (a stream
    repeating one typo pays once)."""
    if not isinstance(word, str) or not word.strip():
        return ""
    near = _nearest(word.strip().casefold(), tuple(valid))
    return f" (did you mean {near!r}?)" if near else ""


SUGGESTIONS_CACHED = 256
"""Mistakes whose nearest valid name is remembered."""


@functools.lru_cache(maxsize=SUGGESTIONS_CACHED)
def _nearest(word: str, valid: tuple[str, ...]) -> str | None:
    folded = {v.casefold(): v for v in valid}
    if not folded or len(word) > 2 * max(map(len, folded)) + 2:
        return None
    near = difflib.get_close_matches(word, list(folded), n=1, cutoff=0.6)
    return folded[near[0]] if near else None
