"""Pace a step function to the wall clock, react at once to what arrives, and say so when the
machine cannot keep up.

Deadlines are absolute (slot ``k`` at ``start + k * period``), so sleep jitter does not
accumulate: a late step is followed by prompt ones until the schedule is met again. Beyond
:data:`BEHIND_S` of lag catching up would only make a burst of steps, so the schedule restarts
from now: robot time slips behind wall time, the slip is counted, and a warning is logged (at
most every 5 s).

Why a ``wake`` event: a command that arrives just after a step would otherwise wait up to a
whole period (2 ms at 500 Hz, ten times Zenoh's own put-to-callback time) before the loop
looks at it. Whoever queues work for the loop sets ``wake``; the loop then runs the step that
was due next at once, so the command is applied and the first step toward it taken within
microseconds. The schedule keeps its phase (the early step used up its slot; the following
one is due at the next slot), so robot time never runs more than one period ahead of the wall
clock and, over any stretch, steps at exactly the fixed rate: a fast command stream cannot
speed the physics up. A second wake within the same period therefore waits for the next slot.
"""

from __future__ import annotations

import _thread
import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

BEHIND_S = 0.05
"""Lag after which the loop stops catching up and lets robot time slip behind wall time."""
WARN_EVERY_S = 5.0


class Wake:
    """The loop's "look now" signal: set from any thread, cleared and waited on by the loop.

    An Event's semantics on a bare lock (locked = not set). Why not ``threading.Event``: its
    ``set`` and ``wait`` run a Condition in Python, ~10-15 us of a command's way from the
    network callback to its first step (measured: wake-up p50 17-32 us with an Event, 11-17
    us with the lock, on this 2-core machine).
    """

    def __init__(self) -> None:
        self._lock = _thread.allocate_lock()
        self._lock.acquire()

    def set(self) -> None:
        try:
            self._lock.release()
        except RuntimeError:  # already set
            pass

    def clear(self) -> None:
        self._lock.acquire(False)

    def is_set(self) -> bool:
        return not self._lock.locked()

    def wait(self, timeout: float) -> bool:
        """Wait until set (True) or ``timeout`` s passed (False); stays set."""
        if self._lock.acquire(True, timeout):
            self._lock.release()
            return True
        return False


STALL_NS = 100_000_000
"""A gap between two steps' starts longer than this is a stall of the loop (``ordering.py``,
rule 3)."""


@dataclass
class LoopStats:
    """What the loop measured about itself (benchmarks and the falling-behind report)."""

    steps: int = 0
    begun: int = 0
    """Steps begun (the one running counts): the robots' step count, ``Agent.due``."""
    begun_ns: int = 0
    """Monotonic ns when the step now running began."""
    stall: tuple[int, int] | None = None
    """The loop's last stall (monotonic ns from, to): no step began in between. The loop's,
    not a robot's: a fleet host's robot at rest runs no cycle of its own for a long while."""
    late: int = 0  # steps that started after their deadline
    slips: int = 0  # times the loop gave up catching up
    early: int = 0  # steps run ahead of their slot because work arrived (``wake``)
    max_lag_s: float = 0.0
    costs_s: deque[float] = field(default_factory=lambda: deque(maxlen=20_000))
    woken: bool = False
    """Whether the step now running was started by ``wake`` rather than by its deadline."""

    def begin(self, now_ns: int) -> None:
        """A step begins at ``now_ns`` (monotonic): counted, a gap since the last one's start
        longer than :data:`STALL_NS` noted as a stall."""
        if self.begun_ns and now_ns - self.begun_ns > STALL_NS:
            self.stall = (self.begun_ns, now_ns)
        self.begun_ns = now_ns
        self.begun += 1


def run_paced(
    step: Callable[[], None], period_s: float, stopped: Callable[[], bool], stats: LoopStats,
    name: str, on_error: Callable[[Exception], None], wake: Wake | None = None,
) -> None:
    """Call ``step`` every ``period_s`` (0: back to back) until ``stopped()``; when ``wake`` is
    set, run the next step at once (at most one period ahead of the schedule, module text).

    ``wake`` is cleared just before each step starts, so what is queued during a step (after
    the step looked) wakes the loop again. An exception from ``step`` goes to ``on_error``
    (and the log, at most every 5 s); the loop goes on, since a robot that silently stops
    stepping is worse than one that says why.
    """
    clock = time.perf_counter
    due = clock()  # the slot of the next step
    last_warn = last_error = -1e9
    while not stopped():
        if wake is not None:
            wake.clear()
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
        due += period_s
        lag = clock() - due
        if lag <= 0.0:
            stats.woken = _wait(due, period_s, wake, stopped, clock)
            stats.early += stats.woken
            continue
        stats.woken = False
        stats.late += 1
        stats.max_lag_s = max(stats.max_lag_s, lag)
        if lag > BEHIND_S:
            stats.slips += 1
            due = clock()
            if t0 - last_warn > WARN_EVERY_S:
                last_warn = t0
                log.warning("%s falls behind real time: %.0f ms late (%d slips)",
                            name, lag * 1e3, stats.slips)


def _wait(due: float, period_s: float, wake: Wake | None,
          stopped: Callable[[], bool], clock: Callable[[], float]) -> bool:
    """Wait for slot ``due``; True when ``wake`` ended the wait early.

    Until the slot before ``due`` has passed, the step just taken was itself early, so a wake
    is left pending (it is seen at that slot): robot time stays within one period of the
    schedule.
    """
    if wake is None:
        delay = due - clock()
        if delay > 0.0:
            time.sleep(delay)
        return False
    ahead = due - period_s - clock()
    if ahead > 0.0:
        time.sleep(ahead)
    delay = due - clock()
    if delay <= 0.0 or stopped():
        return False
    return wake.wait(delay) and clock() < due
