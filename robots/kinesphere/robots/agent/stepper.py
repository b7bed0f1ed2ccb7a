"""Step many bodies' physics side by side: the loop's own thread plus helper threads.

Why threads help at all in Python: MuJoCo releases the GIL inside ``mj_step``, so while one
thread simulates a body another can simulate the next (or run Python). A fleet host's tick
is mostly physics (a 26-DoF NAO step costs ~20-40 us, the robot's Python ~15-25 us), so
splitting the physics over the cores is what keeps dozens of robots at 500 Hz.

Each thread gets a fixed share of the bodies, balanced by their measured cost (greedy,
largest first) and rebalanced every :data:`REBALANCE` ticks. Helpers are persistent (a start
and a done event per tick, no thread created per step); a body that raises is reported for
that body alone, never stops the others.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from kinesphere.robots.agent.body import Body

REBALANCE = 500
"""Ticks between re-partitions of the bodies by their measured cost."""
SMOOTH = 0.05
"""Weight of the newest cost sample in each body's running mean."""


def default_helpers(processes: int = 1) -> int:
    """One helper per core beyond the loop's own, the cores shared by ``processes`` loops (a
    fleet host's workers); at most 3: beyond that the GIL-bound rest of the tick dominates."""
    return max(0, min(3, (os.cpu_count() or 1) // max(1, processes) - 1))


@dataclass
class _Helper:
    thread: threading.Thread | None = None
    start: threading.Event = field(default_factory=threading.Event)
    done: threading.Event = field(default_factory=threading.Event)
    share: list[int] = field(default_factory=list)


class Stepper:
    """``simulate()`` for a list of bodies per tick, over this thread and ``helpers`` more."""

    def __init__(self, helpers: int | None = None) -> None:
        n = default_helpers() if helpers is None else helpers
        if n < 0:
            raise ValueError(f"helper threads must be >= 0, got {n}")
        self._helpers = [_Helper() for _ in range(n)]
        self._bodies: Sequence[Body] = ()
        self._calls: list[Callable[[], None]] = []
        """Each body's :meth:`Body.simulator`, made again when the list of bodies changes."""
        self._errors: list[Exception | None] = []
        self._cost: dict[int, float] = {}  # id(body) -> running mean seconds
        self._own: list[int] = []
        self._key: tuple[object, ...] = ()
        self._running: list[_Helper] = []
        self._ticks = 0
        self._closing = False
        for i, h in enumerate(self._helpers):
            h.thread = threading.Thread(target=self._work, args=(h,), daemon=True,
                                        name=f"physics-{i + 1}")
            h.thread.start()

    @property
    def threads(self) -> int:
        """Threads that step bodies (the caller's included)."""
        return len(self._helpers) + 1

    def simulate(self, bodies: Sequence[Body]) -> list[Exception | None]:
        """Run every body's ``simulate()`` once, this thread taking a share; what each
        raised (None: it stepped)."""
        self.launch(bodies, share=True)
        return self.wait()

    def launch(self, bodies: Sequence[Body], share: bool = False) -> None:
        """Start every body's ``simulate()`` on the helpers and return at once (``share``:
        this thread takes its share first); :meth:`wait` for them before touching a body.
        Without helpers the bodies are simulated here and now. (A caller that passes the
        same list object again, unchanged, saves asking every body for its simulator.)"""
        if bodies is not self._bodies:
            self._bodies = bodies
            self._calls = [b.simulator() for b in bodies]
        self._errors = [None] * len(bodies)
        self._running = []
        if not self._helpers:  # nothing to balance: no clock either
            _run_all(self._calls, self._errors)
            return
        key = (share, *(id(b) for b in bodies))
        self._ticks += 1
        if key != self._key or self._ticks % REBALANCE == 0:
            self._partition(bodies, key, share)
        self._running = [h for h in self._helpers if h.share]
        for h in self._running:
            h.start.set()
        self._run(self._own)

    def wait(self) -> list[Exception | None]:
        """What each body of the last :meth:`launch` raised, once all have stepped."""
        for h in self._running:
            h.done.wait()
            h.done.clear()
        self._running = []
        return self._errors

    def close(self) -> None:
        self._closing = True
        for h in self._helpers:
            h.start.set()
        for h in self._helpers:
            if h.thread is not None:
                h.thread.join(timeout=5.0)

    def _partition(self, bodies: Sequence[Body], key: tuple[object, ...], share: bool) -> None:
        """Greedy: each body, costliest first, to the least loaded thread (this one too
        when it takes a ``share``)."""
        self._key = key
        cost = self._cost
        order = sorted(range(len(bodies)), key=lambda i: -cost.get(id(bodies[i]), 0.0))
        threads = self.threads if share else len(self._helpers)
        shares: list[list[int]] = [[] for _ in range(threads)]
        loads = [0.0] * threads
        for i in order:
            t = loads.index(min(loads))
            shares[t].append(i)
            loads[t] += cost.get(id(bodies[i]), 1e-5)
        if not share:
            shares.insert(0, [])
        self._own = shares[0]
        for h, part in zip(self._helpers, shares[1:], strict=True):
            h.share = part

    def _run(self, indices: Sequence[int]) -> None:
        bodies, calls, errors, cost = self._bodies, self._calls, self._errors, self._cost
        clock = time.perf_counter
        for i in indices:
            t0 = clock()
            try:
                calls[i]()
            except Exception as exc:  # reported for this body; the others step on
                errors[i] = exc
            k = id(bodies[i])
            cost[k] = cost.get(k, 0.0) * (1.0 - SMOOTH) + (clock() - t0) * SMOOTH

    def _work(self, h: _Helper) -> None:
        while True:
            h.start.wait()
            h.start.clear()
            if self._closing:
                return
            self._run(h.share)
            h.done.set()


def _run_all(calls: Sequence[Callable[[], None]], errors: list[Exception | None]) -> None:
    """Every call in turn, one ``try`` around them all (entered once per tick, not per body);
    a call that raises is reported at its index and the rest run on."""
    start = 0
    while start < len(calls):
        i = start
        try:
            for i in range(start, len(calls)):
                calls[i]()
            return
        except Exception as exc:  # reported for this body; the others step on
            errors[i] = exc
            start = i + 1
