"""A databank process under a flood of invented keys and padded requests stays bounded in memory.

Before: each error answer was cached under its key (3,000 unknown-platform keys of 30 KB added
179 MB), compound answers were cached under their whole padded payloads (2,000 added 135 MB),
and the caches were bounded by entry count (65,536), not bytes. Now names are capped at 64
characters (longer ones are ``malformed``, not echoed), errors live in a 1 MiB cache, answers
in byte-bounded LRU caches. The flood runs against ``kinesphere databank serve`` with every
shipped databank; RSS is read from the process before and after.
"""

from __future__ import annotations

import random
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
import zenoh
from test_databank_support import Tokens, peer, serve_process
from test_soak_support import MIB, SCALE, Tally, mib, rss

from kinesphere import protocol as pr
from kinesphere.keyexpr import Keys
from kinesphere.services.databank.replies import DEFAULT_BUDGET
from kinesphere.zconfig import LOOPBACK_ANY_PORT, close_session, loopback_hub

KEYS = Keys("kflood")
ARM = ("limb_11", "distal_11", "left-high")  # Baxter's right arm from the shoulder
BATCH = 16
OVERHEAD = 24 * MIB
"""Receiving 64 KiB payloads costs ~20 MiB of Zenoh buffers and allocator arenas (measured: a
plateau, the same after 500 or 4,000 such requests), plus the few MiB of pose answers the
CI-size flood legitimately caches."""
GROWTH_BOUND = DEFAULT_BUDGET.errors + DEFAULT_BUDGET.compounds + OVERHEAD
"""What the CI-size flood may add: the error and compound caches full, plus OVERHEAD. The
answer cache (32 MiB) cannot fill at this size; at soak size the bound adds it."""
PLATEAU = 8 * MIB
"""What the second half of the flood may add to the first: bounded means it stops growing."""


def growth_bound() -> int:
    return GROWTH_BOUND + (DEFAULT_BUDGET.answers if SCALE > 1 else 0)


class Flood:
    """Pipelined queries (BATCH in flight) with every reply's outcome tallied."""

    def __init__(self, session: zenoh.Session, tally: Tally) -> None:
        self.session = session
        self.tally = tally
        self._pending: list[zenoh.Handler[zenoh.Reply]] = []

    def get(self, key: str, payload: bytes | None = None) -> None:
        self._pending.append(self.session.get(key, payload=payload, timeout=10.0))
        if len(self._pending) >= BATCH:
            self.drain()

    def drain(self) -> None:
        for handler in self._pending:
            replies = list(handler)
            if not replies:
                self.tally.add("no answer")
            for reply in replies:
                if reply.ok is not None:
                    self.tally.add("ok")
                else:
                    assert reply.err is not None
                    self.tally.add(pr.error_from_reply(reply.err.payload.to_bytes()).code)
        self._pending.clear()


def reference(session: zenoh.Session) -> bytes:
    replies = list(session.get(KEYS.pose("baxter", *ARM, 2), timeout=10.0))
    assert len(replies) == 1 and replies[0].ok is not None, replies
    return replies[0].ok.payload.to_bytes()


def compound(i: int, pad: int) -> bytes:
    """A valid compound of Baxter's two arms, made unique and ``pad`` bytes long by an
    unknown field (which decoders skip)."""
    parts = [{"limb": "limb_11", "origin": "distal_11", "direction": "left-high", "size": 2},
             {"limb": "limb_21", "origin": "distal_21", "direction": "right-high", "size": 2}]
    head = msgspec.msgpack.encode({"type": "compound_request", "parts": parts, "n": i})
    filler = pad - len(head) - 8
    return msgspec.msgpack.encode({"type": "compound_request", "parts": parts, "n": i,
                                   "pad": random.randbytes(max(0, filler))})


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[zenoh.Session, int]]:
    with loopback_hub() as (_hub, endpoint):
        client = peer(endpoint)
        tokens = Tokens(client, KEYS)
        args = ["--prefix", KEYS.prefix, "--connect", endpoint, "--listen", LOOPBACK_ANY_PORT]
        try:
            with serve_process(args, "flood") as proc:
                assert tokens.wait("flood", timeout=60), "databank did not start"
                yield client, proc.pid
                assert proc.poll() is None, "the databank died during the flood"
                proc.terminate()
                _, err = proc.communicate(timeout=20)
                assert proc.returncode == 0, err
                assert "Traceback" not in err, err
                # refusals are rate-limited: a few lines, not one per request
                assert len(err.splitlines()) < 20, err
        finally:
            tokens.close()
            close_session(client)


def test_flood_of_invented_keys_and_padded_requests_is_bounded(
    served: tuple[zenoh.Session, int],
) -> None:
    client, pid = served
    good = reference(client)
    tally = Tally("databank flood")
    flood = Flood(client, tally)
    for i in range(200):  # warm up: caches, Zenoh buffers, the allocator
        flood.get(KEYS.pose("baxter", *ARM, 1 + i / 200))
        flood.get(KEYS.compound("baxter"), compound(i, 1000))
    flood.drain()
    tally.sent, tally.codes = 0, type(tally.codes)()
    before = rss(pid)
    n = 3000 * SCALE
    mid = before
    for i in range(n):
        if i == n // 2:
            flood.drain()
            mid = rss(pid)
        # a 30 KB unknown platform name: malformed (too long), never cached whole
        flood.get(f"{KEYS.prefix}/ecl/{i:08d}{'x' * 30_000}/catalogue")
        # an unknown platform with a legal name: unknown_platform, cached in the error cache
        flood.get(KEYS.catalogue(f"ghost-{i}-{'g' * 48}"))
        # a well-formed key for a new fractional size: a real answer each time
        flood.get(KEYS.pose("baxter", *ARM, 1 + i / n))
        if i % 3 == 0:  # 64 KiB compounds, each distinct
            flood.get(KEYS.compound("baxter"), compound(i, pr.MAX_PAYLOAD - 16))
        if i % 500 == 0:
            flood.drain()
            assert reference(client) == good  # valid queries still answered, byte-identical
    flood.drain()
    after = rss(pid)
    tally.extra = {"RSS before": mib(before), "half-way": mib(mid), "after": mib(after),
                   "bound": f"+{mib(growth_bound())}"}
    tally.report()
    assert tally.codes["malformed"] == n and tally.codes["unknown_platform"] == n
    assert tally.codes["ok"] == n + len(range(0, n, 3))
    assert set(tally.codes) == {"malformed", "unknown_platform", "ok"}
    assert after - before < growth_bound(), tally.report()
    assert after - mid < PLATEAU, tally.report()
