"""Pace a step function to the wall clock, and say so when the machine cannot keep up.

Deadlines are absolute (``start + k * period``), so sleep jitter does not accumulate: a late
step is followed by prompt ones until the schedule is met again. Beyond :data:`BEHIND_S` of lag
catching up would only make a burst of steps, so the schedule restarts from now: robot time
slips behind wall time, the slip is counted, and a warning is logged (at most every 5 s).
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

BEHIND_S = 0.05
"""Lag after which the loop stops catching up and lets robot time slip behind wall time."""
WARN_EVERY_S = 5.0


@dataclass
class LoopStats:
    """What the loop measured about itself (benchmarks and the falling-behind report)."""

    steps: int = 0
    late: int = 0  # steps that started after their deadline
    slips: int = 0  # times the loop gave up catching up
    max_lag_s: float = 0.0
    costs_s: deque[float] = field(default_factory=lambda: deque(maxlen=20_000))


def run_paced(
    step: Callable[[], None], period_s: float, stopped: Callable[[], bool], stats: LoopStats,
    name: str, on_error: Callable[[Exception], None],
) -> None:
    """Call ``step`` every ``period_s`` (0: back to back) until ``stopped()``.

    An exception from ``step`` goes to ``on_error`` (and the log, at most every 5 s); the loop
    goes on, since a robot that silently stops stepping is worse than one that says why.
    """
    clock = time.perf_counter
    next_t = clock()
    last_warn = last_error = -1e9
    while not stopped():
        t0 = clock()
        try:
            step()
        except Exception as exc:
            if t0 - last_error > WARN_EVERY_S:
                last_error = t0
                log.exception("%s: control step failed", name)
            on_error(exc)
        stats.costs_s.append(clock() - t0)
        if period_s == 0.0:
            continue
        next_t += period_s
        delay = next_t - clock()
        if delay > 0.0:
            time.sleep(delay)
            continue
        stats.late += 1
        stats.max_lag_s = max(stats.max_lag_s, -delay)
        if -delay > BEHIND_S:
            stats.slips += 1
            next_t = clock()
            if t0 - last_warn > WARN_EVERY_S:
                last_warn = t0
                log.warning("%s falls behind real time: %.0f ms late (%d slips)",
                            name, -delay * 1e3, stats.slips)
