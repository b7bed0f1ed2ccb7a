"""Answers the nested solver computes, off Zenoh's threads.

Pointing nested parts (an upper arm and its forearm, a cut limb such as the upper arm) takes a
mink solve: tens of milliseconds, a few hundred on a cold start, far longer than the hot path
may hold one of Zenoh's threads. Such queries are kept (not dropped) and answered by one
worker thread, in order, from a bounded queue: a flood of distinct nested requests is refused
with ``unavailable`` instead of queued without end, and repeated ones cost a cache hit (the
ECL keeps its solutions, the service its encoded answers).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Final

import zenoh

from kinesphere.services.databank.replies import DEFERRED, Deferred, EncodedReply, error, send
from kinesphere.services.databank.worker import Worker

log = logging.getLogger(__name__)
MAX_SOLVES: Final = 64
"""Nested queries waiting for the solver at most (each holds its query and payload)."""


class Solves:
    """One worker answering the queries that need the nested solver."""

    def __init__(self, replica_id: str, max_jobs: int = MAX_SOLVES) -> None:
        self._worker = Worker(f"databank-{replica_id}-solves", max_jobs)

    def start(self) -> None:
        self._worker.start()

    def stop(self) -> None:
        """Answer the queued queries first."""
        self._worker.stop()

    def waiting(self) -> int:
        """Queries waiting for the solver or being solved."""
        return self._worker.waiting()

    def defer(self, query: zenoh.Query, compute: Callable[[], EncodedReply]
              ) -> EncodedReply | Deferred:
        """Queue ``query`` for the worker, which replies ``compute()`` on the query's own key
        and drops it; :data:`DEFERRED` tells the caller to keep the query meanwhile."""
        key = query.key_expr
        if not self._worker.submit(lambda: self._answer(query, key, compute)):
            return error("unavailable", "too many nested solves queued; retry later")
        return DEFERRED

    @staticmethod
    def _answer(query: zenoh.Query, key: zenoh.KeyExpr,
                compute: Callable[[], EncodedReply]) -> None:
        with query:
            try:
                answer = compute()
            except Exception as exc:  # a bug: say so rather than leave the querier waiting
                log.exception("nested query %.200s failed", key)
                answer = error("internal", f"{type(exc).__name__}: {exc}")
            send(query, key, answer)
