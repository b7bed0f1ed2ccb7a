"""Zenoh on loopback for the tests: key prefixes, the hub's shape, peer sessions."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import NamedTuple

import zenoh

from kinesphere.keyexpr import Keys
from kinesphere.zconfig import loopback_config, open_session, undeclare

KEYS = Keys()
"""The default prefix: what every process uses unless told, so what a user's commands use,
and what the shared databank (``tests/conftest.py``) serves."""
OWN_KEYS = Keys("kstest")
"""A prefix of the tests' own: services a test declares itself on the shared hub must not meet
the shared databank, which answers every platform under the default prefix."""
NO_ROBOTS = 0.0
"""A replay's ``answers_for`` when it puts to plain subscribers: no robot is there to answer,
so it waits for none (else each replay of commands waits its full time for answers)."""


class Hub(NamedTuple):
    """A loopback Zenoh session every test process joins, and the endpoint to join it at."""

    session: zenoh.Session
    endpoint: str


def peer(endpoint: str) -> zenoh.Session:
    """A peer session joined to the hub at ``endpoint``."""
    return open_session(config=loopback_config(endpoint))


@contextmanager
def awaiting_token(session: zenoh.Session, key: str) -> Iterator[threading.Event]:
    """For the block, a liveliness subscriber (with history) on ``key``: the event is set once
    a token appears there (start a process inside, then wait on it)."""
    up = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            up.set()

    sub = session.liveliness().declare_subscriber(key, on_token, history=True)
    try:
        yield up
    finally:
        undeclare(sub)
