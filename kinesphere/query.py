"""One answer to a Zenoh ``get``: the first reply, decoded, or the error it carries; every
good answer (:func:`get_all`); and which ``get`` asks a databank what some parts mean
(:func:`pose_query`).

A ``get`` that ends without any reply means no queryable was reachable at that moment (the
one that had the query died, or declarations have not arrived yet). With ``retry=True`` such
a ``get`` is repeated until ``timeout`` has passed; a reply, good or bad, ends the request.
Errors come back as KinesphereError with the replier's code, ``unavailable`` when nobody
answered in time or Zenoh itself failed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from typing import TypeVar

import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.protocol import (
    CompoundRequest,
    SpatialCommand,
    decode,
    encode,
    error_from_reply,
)

log = logging.getLogger(__name__)

T = TypeVar("T")
RETRY_PAUSE_S = 0.02
"""Pause between two ``get`` that found nobody, so a retry loop does not spin."""


def get_one(
    source: zenoh.Session | zenoh.Querier,
    key: str,
    decode_type: type[T],
    payload: bytes | None = None,
    *,
    timeout: float,
    retry: bool = False,
    every_replica: bool = False,
    no_answer: str | None = None,
) -> T:
    """The first reply to ``get(key)`` on ``source``, decoded as ``decode_type``.

    ``source`` is a session, or a querier declared on ``key`` (its own timeout then bounds
    each ``get``). ``retry`` repeats a ``get`` that ended without replies until ``timeout``
    seconds have passed. ``every_replica`` sends the query to every complete queryable and
    returns the first good reply, or raises the first error when none is good; otherwise the
    first reply, good or bad, decides. ``no_answer`` is the message of the ``unavailable``
    error raised when nobody answered (default: ``no answer to <key> within <timeout> s``).
    """
    deadline = time.monotonic() + timeout
    target = zenoh.QueryTarget.ALL_COMPLETE if every_replica else zenoh.QueryTarget.BEST_MATCHING
    while True:
        remaining = deadline - time.monotonic()
        if retry and remaining <= 0:
            break
        first_error: KinesphereError | None = None
        try:
            if isinstance(source, zenoh.Querier):
                replies = source.get(payload=payload)
            else:
                replies = source.get(
                    key,
                    payload=payload,
                    target=target,
                    consolidation=zenoh.ConsolidationMode.NONE,
                    timeout=max(remaining, 0.0) if retry else timeout,
                )
            for reply in replies:
                if reply.ok is not None:
                    return decode(reply.ok.payload, decode_type)
                assert reply.err is not None
                first_error = first_error or error_from_reply(reply.err.payload)
                if not every_replica:
                    break
        except zenoh.ZError as exc:
            raise KinesphereError("unavailable", f"zenoh: {exc}") from None
        if first_error is not None:
            raise first_error
        if not retry:
            break
        time.sleep(min(RETRY_PAUSE_S, max(0.0, deadline - time.monotonic())))
    raise KinesphereError("unavailable", no_answer or f"no answer to {key} within {timeout:g} s")


def get_all(session: zenoh.Session, key: str, decode_type: type[T], *, timeout: float
            ) -> list[T]:
    """Every good reply to ``get(key)`` within ``timeout``, decoded as ``decode_type``, from
    every queryable (no consolidation): for gathering what several holders know. Error replies
    and replies that do not decode are skipped (logged at debug): one bad peer must not hide
    the others. Raises KinesphereError ``unavailable`` when Zenoh itself fails (the session is
    closing)."""
    found: list[T] = []
    try:
        replies = session.get(key, timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE)
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                found.append(decode(reply.ok.payload, decode_type))
            except KinesphereError as exc:
                log.debug("reply from %s ignored: %s", reply.ok.key_expr, exc)
    except zenoh.ZError as exc:
        raise KinesphereError("unavailable", f"zenoh: {exc}") from None
    return found


def pose_query(keys: Keys, platform: str, parts: Sequence[SpatialCommand]
               ) -> tuple[str, bytes | None]:
    """The key and payload that ask ``platform``'s databank what ``parts`` mean: one part's
    own pose key, or the compound key with the parts (several, or one that must be exact:
    a pose key cannot say "exact only")."""
    if len(parts) == 1 and not parts[0].exact:
        p = parts[0]
        return keys.pose(platform, p.limb, p.origin, p.direction, p.size), None
    return keys.compound(platform), encode(CompoundRequest(parts=list(parts)))
