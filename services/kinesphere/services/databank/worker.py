"""One background thread for slow jobs (SQL writes), so Zenoh's threads never wait on disk.

The queue is bounded: each job holds a request payload (up to 64 KiB), so a flood of records
must be refused, not queued without end.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from typing import Final

log = logging.getLogger(__name__)
MAX_JOBS: Final = 64
"""Jobs waiting at most; :meth:`Worker.submit` refuses more."""


class Worker:
    """Runs submitted jobs in order; :meth:`stop` finishes the queued ones first."""

    def __init__(self, name: str, max_jobs: int = MAX_JOBS) -> None:
        self._jobs: queue.Queue[Callable[[], None] | None] = queue.Queue(max_jobs)
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._lock = threading.Lock()
        self._waiting = 0

    def waiting(self) -> int:
        """Jobs submitted and not finished yet (queued or running)."""
        return self._waiting

    def start(self) -> None:
        self._thread.start()

    def submit(self, job: Callable[[], None]) -> bool:
        """Queue ``job``; False (and not queued) when MAX_JOBS are already waiting."""
        with self._lock:
            try:
                self._jobs.put_nowait(job)
            except queue.Full:
                return False
            self._waiting += 1
        return True

    def stop(self, timeout: float = 30.0) -> None:
        if self._thread.is_alive():
            self._jobs.put(None)
            self._thread.join(timeout)
            if self._thread.is_alive():
                log.warning("%s still busy after %.0f s; leaving it", self._thread.name, timeout)

    def _run(self) -> None:
        while (job := self._jobs.get()) is not None:
            try:
                job()
            except Exception:
                log.exception("background job failed")
            finally:
                with self._lock:
                    self._waiting -= 1
