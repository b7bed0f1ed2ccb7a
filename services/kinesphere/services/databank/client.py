"""Asking the databank from Python: one answer per request, riding over replica failover.

A ``get`` that ends without any reply means no queryable was reachable at that moment (the
replica that had the query died, or declarations have not arrived yet), so it is retried
until the deadline (:func:`kinesphere.query.get_one`); a reply, good or bad, ends the
request. Errors come back as KinesphereError with the databank's code, ``unavailable`` when
nobody answered in time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TypeVar

import msgspec
import zenoh

from kinesphere import hints
from kinesphere.keyexpr import EXACT, KEYS, Keys
from kinesphere.protocol import (
    Catalogue,
    CompoundRequest,
    Pose,
    RecordRequest,
    SpatialCommand,
    encode,
)
from kinesphere.query import get_one
from kinesphere.services.options import QueryOptions
from kinesphere.sizes import parse_size

T = TypeVar("T")
DEFAULT_TIMEOUT = QueryOptions.timeout_s


def request(
    session: zenoh.Session,
    key: str,
    type_: type[T],
    *,
    payload: bytes | None = None,
    timeout: float = DEFAULT_TIMEOUT,
    every_replica: bool = False,
) -> T:
    """The first reply to ``get(key)`` decoded as ``type_``, retried while nobody answers.

    ``every_replica`` sends the query to every complete queryable (all replicas) and returns
    the first good reply, or raises the first error when none is good.
    """
    return get_one(
        session,
        key,
        type_,
        payload,
        timeout=timeout,
        retry=True,
        every_replica=every_replica,
        no_answer=f"no databank answered {key} within {timeout:g} s; is "
        f"'{hints.serve_databank()}' running for this platform and reachable (--connect)?",
    )


def query_pose(
    session: zenoh.Session,
    platform: str,
    limb: str,
    origin: str,
    direction: str,
    size: float | str,
    *,
    keys: Keys = KEYS,
    timeout: float = DEFAULT_TIMEOUT,
    exact: bool = False,
) -> Pose:
    """f_SB over the network; ``size`` may be text (``far``, ``2.5``). A direction the limb
    lacks comes back substituted (``Pose.substitutions``) unless ``exact``."""
    key = keys.pose(platform, limb, origin, direction, parse_size(size))
    return request(session, key + EXACT if exact else key, Pose, timeout=timeout)


def query_catalogue(
    session: zenoh.Session, platform: str, *, keys: Keys = KEYS, timeout: float = DEFAULT_TIMEOUT
) -> Catalogue:
    return request(session, keys.catalogue(platform), Catalogue, timeout=timeout)


def query_compound(
    session: zenoh.Session,
    platform: str,
    parts: Sequence[SpatialCommand],
    last_wins: bool = False,
    *,
    keys: Keys = KEYS,
    timeout: float = DEFAULT_TIMEOUT,
) -> Pose:
    payload = encode(CompoundRequest(parts=list(parts), last_wins=last_wins))
    return request(session, keys.compound(platform), Pose, payload=payload, timeout=timeout)


def record_pose(
    session: zenoh.Session,
    platform: str,
    limb: str,
    origin: str,
    direction: str,
    size: int,
    joints: Mapping[str, float],
    *,
    keys: Keys = KEYS,
    timeout: float = DEFAULT_TIMEOUT,
) -> Pose:
    """Super-user write, sent to every replica (each writable one stores it; recording is
    idempotent, so retrying is safe); ``forbidden`` when no replica has writes enabled."""
    req = RecordRequest(
        limb=limb, origin=origin, direction=direction, size=size, joints=dict(joints)
    )
    payload = encode(req)
    key = keys.record(platform)
    return request(session, key, Pose, payload=payload, timeout=timeout, every_replica=True)


def to_builtins(msg: msgspec.Struct) -> object:
    """A message as plain JSON-able data (non-finite floats become None)."""
    return msgspec.json.decode(msgspec.json.encode(msg))
