"""Pre-encoded answers, so a repeated query costs one dict hit and one Zenoh call.

Encoding a Pose with msgspec and wrapping it in ZBytes costs more than the rest of the hot
path together, and agents ask the same few keys again and again. Answers (errors included:
a flood of bad keys must not cost more than good ones) are kept per request text until the
databank changes. Caches are bounded in bytes (keys and payloads counted), errors in a small
one of their own, so a querier inventing keys can neither grow memory nor evict good answers.
"""

from __future__ import annotations

import threading
from collections.abc import Hashable
from dataclasses import dataclass
from typing import Final, NamedTuple

import msgspec
import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.lru import Lru
from kinesphere.protocol import MAX_PAYLOAD, Error, encode

ANSWER_BYTES: Final = 32 * 1024 * 1024
"""Budget of the answers to well-formed pose and catalogue keys (a few thousand per platform,
but every fractional size is a key of its own)."""
ERROR_BYTES: Final = 1024 * 1024
"""Budget of cached errors: a flood of invented keys may not cost more than good ones to
answer, nor push good answers out or hold much memory."""
COMPOUND_BYTES: Final = 16 * 1024 * 1024
"""Budget of compound answers, keyed by their (up to 64 KiB) request payloads."""


@dataclass(frozen=True)
class CacheBudget:
    """Bytes each reply cache of a databank service may hold (:func:`entry_bytes`)."""

    answers: int = ANSWER_BYTES
    errors: int = ERROR_BYTES
    compounds: int = COMPOUND_BYTES


DEFAULT_BUDGET: Final = CacheBudget()


class EncodedReply(NamedTuple):
    """An encoded reply: ``ok`` goes out with ``query.reply``, otherwise ``reply_err``."""

    ok: bool
    payload: zenoh.ZBytes


class Deferred:
    """Marks a query a worker answers later: the callback must not drop it."""


DEFERRED: Final = Deferred()


def ok(msg: msgspec.Struct) -> EncodedReply:
    return EncodedReply(True, zenoh.ZBytes(encode(msg)))


def err(exc: KinesphereError) -> EncodedReply:
    return EncodedReply(False, zenoh.ZBytes(encode(Error.from_exception(exc))))


def error(code: str, message: str) -> EncodedReply:
    return err(KinesphereError(code, message))


def send(query: zenoh.Query, key: zenoh.KeyExpr | str, answer: EncodedReply) -> None:
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


ENTRY_BYTES: Final = 384
"""Bytes counted per cached answer on top of its key and payload: the key and EncodedReply objects,
the ZBytes and its buffer header, the dict slot (with the table's spare room) and the LRU link.
Measured with real pose answers: ~320 bytes, so a full 32 MiB answer cache costs the process
~30 MiB of RSS (tests/services/test_databank_cache.py); 256 undercounted it (35 MiB)."""


def entry_bytes(key: Hashable, answer: EncodedReply) -> int:
    """What one cache entry is charged: its key's and payload's lengths plus ENTRY_BYTES."""
    parts = key if isinstance(key, tuple) else (key,)
    return ENTRY_BYTES + len(answer.payload) + sum(
        len(p) for p in parts if isinstance(p, (str, bytes))
    )


class ReplyCache:
    """Answers by request (key text, or key and payload), bounded in bytes (:func:`entry_bytes`
    each), least recently used evicted first, all dropped when a databank changes.

    Readers call :meth:`get` without a lock (:meth:`kinesphere.lru.Lru.get`). A writer passes
    the :attr:`generation` it read before computing, so an answer computed from the old
    databank while a record was swapping it in is never stored. :meth:`put` returns the
    answer, so a miss reads ``return cache.put(key, compute(), g)``. An answer bigger than a
    quarter of the budget is not cached at all.
    """

    def __init__(self, max_bytes: int) -> None:
        if max_bytes < 4 * ENTRY_BYTES:
            raise ValueError(f"a reply cache needs at least {4 * ENTRY_BYTES} bytes, got "
                             f"{max_bytes}")
        # no entry costs less than ENTRY_BYTES: the byte budget bounds the count too
        self._answers: Lru[Hashable, EncodedReply] = Lru(
            max_bytes // ENTRY_BYTES, max_bytes, entry_bytes, largest=max_bytes // 4)
        self.get = self._answers.get
        """``get(key)``: the answer (now the most recently used), or None."""
        self.max_bytes = max_bytes
        self._lock = threading.Lock()
        self.generation = 0

    def __len__(self) -> int:
        return len(self._answers)

    @property
    def bytes(self) -> int:
        """Bytes charged (:func:`entry_bytes`) by the answers held now."""
        return self._answers.bytes

    def put(self, key: Hashable, answer: EncodedReply, generation: int) -> EncodedReply:
        with self._lock:
            if generation == self.generation:
                self._answers.put(key, answer)
        return answer

    def invalidate(self) -> None:
        with self._lock:
            self.generation += 1
            self._answers.clear()
