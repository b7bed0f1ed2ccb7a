"""A clock the test sets by hand, for code that takes its clock as a callable (rate limits,
timeouts, leases): time passes only when the test says so."""

from __future__ import annotations


class ManualClock:
    """``clock()`` is ``now`` (s), which the test assigns."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now
