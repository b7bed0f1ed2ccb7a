"""Waiting for what another thread or process does: one upper bound, one poller, one way to
stop a process.

Tests wait on events (a message, a state matching a predicate) wherever one exists; this
poller is for state that changes without an event to wait on.
"""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Callable
from typing import Any

import pytest

WAIT_S = 60.0
"""Upper bound for start-up and events on a loaded 2-core machine; tests finish far sooner
(a larger bound only makes a failing test fail later)."""


def until(cond: Callable[[], bool], timeout: float, what: str, every: float = 0.05,
          explain: Callable[[], object] | None = None,
          guard: Callable[[], None] | None = None) -> None:
    """Poll ``cond`` until it holds; fail naming ``what`` (and ``explain()``) after ``timeout``.
    ``guard`` runs before each poll and raises to end the wait early (``Supervisor.check``: a
    child that died will not make ``cond`` hold)."""
    deadline = time.monotonic() + timeout
    while True:
        if guard is not None:
            guard()
        if cond():
            return
        if time.monotonic() > deadline:
            extra = f"\n{explain()}" if explain is not None else ""
            pytest.fail(f"timed out after {timeout:g} s waiting for {what}{extra}")
        time.sleep(every)


def stop_process(proc: subprocess.Popen[Any], timeout: float = WAIT_S) -> int:
    """SIGTERM ``proc`` (thawed first, in case a test froze it) and wait for it to end; killed
    if it has not after ``timeout`` seconds. Its exit status."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGCONT)
        proc.send_signal(signal.SIGTERM)
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()
