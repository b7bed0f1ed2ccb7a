"""Helpers for the fuzz and flood tests, which run at two sizes from the same code.

``make test`` runs them at :data:`SCALE` 1 (a few seconds each); ``make soak`` sets
``KINESPHERE_SOAK_SCALE`` (default there: 20) and prints each test's tally, the numbers
docs/soak.md quotes. Not a test module itself (pytest collects nothing here).
"""

from __future__ import annotations

import collections
import os
import sys

import psutil

SCALE = max(1, int(os.environ.get("KINESPHERE_SOAK_SCALE", "1")))
"""How many times the CI size each fuzz and flood test runs."""
MIB = 1024 * 1024


def rss(pid: int) -> int:
    """Resident set size of process ``pid`` in bytes."""
    return int(psutil.Process(pid).memory_info().rss)


class FloodTally:
    """Counts of what a flood sent and what came back, printed as one report line."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.sent = 0
        self.codes: collections.Counter[str] = collections.Counter()
        self.extra: dict[str, object] = {}

    def add(self, code: str) -> None:
        """One outcome (a reply's code, ``ok``, ``no answer``); ``sent`` counts requests."""
        self.codes[code] += 1

    def report(self) -> str:
        codes = ", ".join(f"{c} {n}" for c, n in sorted(self.codes.items()))
        extra = "".join(f"; {k} {v}" for k, v in self.extra.items())
        line = f"SOAK {self.name} (scale {SCALE}): sent {self.sent}"
        line += f"; {codes}{extra}" if codes else extra
        print(line, file=sys.stderr if SCALE == 1 else sys.stdout, flush=True)
        return line


def mib(n: int) -> str:
    return f"{n / MIB:.1f} MiB"
