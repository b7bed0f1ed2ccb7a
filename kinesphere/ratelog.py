"""Log lines a peer can trigger, at most one per key per interval, in bounded memory.

Anything a remote peer can cause (a malformed request, an access-control denial, a refused
record) must not let that peer flood the log or grow a table: repeats of one key within
``every`` seconds are counted and reported with the next line, and past ``max_keys`` the
least recently logged keys are forgotten.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Hashable

from kinesphere.lru import Lru

EVERY_S = 10.0
"""Default interval between two lines of one key."""
MAX_KEYS = 256
"""Default number of keys remembered; a peer inventing keys only evicts old ones."""


class RateLog:
    """``log(key, msg, *args)``: log ``msg`` unless ``key`` already logged ``burst`` lines in
    the last ``every`` s.

    The first line after a quiet spell says how many were held back: ``... (+12 more in
    10 s)``. Thread-safe; :meth:`__call__` returns whether it logged.
    """

    def __init__(
        self,
        logger: logging.Logger,
        level: int = logging.WARNING,
        every: float = EVERY_S,
        max_keys: int = MAX_KEYS,
        clock: Callable[[], float] = time.monotonic,
        burst: int = 1,
    ) -> None:
        self._log = logger
        self._level = level
        self._every = every
        self._clock = clock
        self._burst = burst
        # key -> [window start, lines in the window, lines held back]
        self._seen: Lru[Hashable, list[float]] = Lru(max_keys)
        self._lock = threading.Lock()
        self.held = 0
        """Lines held back since start (all keys)."""

    def __len__(self) -> int:
        return len(self._seen)

    def allow(self, key: Hashable) -> tuple[bool, int]:
        """Whether ``key`` may log now, and how many of its lines were held back before (to
        report with this one); counts a refusal."""
        now = self._clock()
        with self._lock:
            entry = self._seen.peek(key)
            if entry is not None and now - entry[0] < self._every:
                if entry[1] >= self._burst:
                    entry[2] += 1
                    self.held += 1
                    return False, 0
                entry[1] += 1
                return True, 0
            held = int(entry[2]) if entry is not None else 0
            self._seen.put(key, [now, 1, 0])
            return True, held

    def __call__(self, key: Hashable, msg: str, *args: object) -> bool:
        ok, held = self.allow(key)
        if not ok:
            return False
        if held:
            msg, args = f"{msg} (+%d more in %.0f s)", (*args, held, self._every)
        self._log.log(self._level, msg, *args)
        return True
