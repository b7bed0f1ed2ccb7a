"""Pre-encoded answers, so a repeated query costs one dict hit and one Zenoh call.

Encoding a Pose with msgspec and wrapping it in ZBytes costs more than the rest of the hot
path together, and agents ask the same few keys again and again. Answers (errors included:
a flood of bad keys must not cost more than good ones) are kept per request text until the
databank changes. The cache is bounded so a querier inventing keys cannot grow it forever.
"""

from __future__ import annotations

import threading
from collections.abc import Hashable
from typing import Final, NamedTuple

import msgspec
import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.protocol import MAX_PAYLOAD, Error, encode

MAX_ENTRIES: Final = 65_536


class Answer(NamedTuple):
    """An encoded reply: ``ok`` goes out with ``query.reply``, otherwise ``reply_err``."""

    ok: bool
    payload: zenoh.ZBytes


class Deferred:
    """Marks a query a worker answers later: the callback must not drop it."""


DEFERRED: Final = Deferred()


def ok(msg: msgspec.Struct) -> Answer:
    return Answer(True, zenoh.ZBytes(encode(msg)))


def err(exc: KinesphereError) -> Answer:
    return Answer(False, zenoh.ZBytes(encode(Error.from_exception(exc))))


def error(code: str, message: str) -> Answer:
    return err(KinesphereError(code, message))


def send(query: zenoh.Query, key: zenoh.KeyExpr | str, answer: Answer) -> None:
    """Reply ``answer`` to ``query`` on ``key`` (errors carry no key)."""
    if answer.ok:
        query.reply(key, answer.payload)
    else:
        query.reply_err(answer.payload)


def request_bytes(query: zenoh.Query, what: str) -> bytes:
    """The query's payload, or ``malformed`` when it is missing or larger than MAX_PAYLOAD."""
    payload = query.payload
    if payload is None or len(payload) == 0:
        raise KinesphereError("malformed", f"{what} query needs a {what} payload (MessagePack)")
    if len(payload) > MAX_PAYLOAD:
        raise KinesphereError(
            "malformed", f"{what} payload of {len(payload)} bytes exceeds {MAX_PAYLOAD} bytes"
        )
    return payload.to_bytes()


class ReplyCache:
    """Answers by request (key text, or key and payload), all dropped when a databank changes.

    Readers call :meth:`get` without a lock (a dict read is atomic under the GIL). A writer
    passes the :attr:`generation` it read before computing, so an answer computed from the
    old databank while a record was swapping it in is never stored. :meth:`put` returns the
    answer, so a miss reads ``return cache.put(key, compute(), generation)``.
    """

    def __init__(self, max_entries: int = MAX_ENTRIES) -> None:
        self._answers: dict[Hashable, Answer] = {}
        self._max = max_entries
        self._lock = threading.Lock()
        self.generation = 0
        self.get = self._answers.get
        """``get(key) -> Answer | None``, bound once for the hot path."""

    def __len__(self) -> int:
        return len(self._answers)

    def put(self, key: Hashable, answer: Answer, generation: int) -> Answer:
        with self._lock:
            if generation == self.generation:
                if len(self._answers) >= self._max:
                    self._answers.clear()
                self._answers[key] = answer
        return answer

    def invalidate(self) -> None:
        with self._lock:
            self.generation += 1
            self._answers.clear()
