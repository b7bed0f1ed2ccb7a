"""Signal handlers installed for a block of work, the previous ones restored after it.

Every long-running command (agent, databank, router, ``up``, the operator's clients) stops
cleanly on SIGTERM/SIGINT; this is the one place that installs and restores the handlers.
Python only lets the main thread do either.
"""

from __future__ import annotations

import signal
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from types import FrameType

Handler = Callable[[int, FrameType | None], object]


@contextmanager
def handle_signals(
    handler: Handler, signums: Iterable[int] = (signal.SIGINT, signal.SIGTERM)
) -> Iterator[None]:
    """Run the block with ``handler`` for each of ``signums``; restore the old handlers after."""
    previous = {s: signal.signal(s, handler) for s in signums}
    try:
        yield
    finally:
        for s, old in previous.items():
            signal.signal(s, old)
