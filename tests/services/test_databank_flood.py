"""A databank process under a flood of invented keys and padded requests stays bounded in
memory, and under fuzzed requests answers every one with a named error.

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

from kinesphere import protocol as pr
from kinesphere.errors import ERROR_CODES
from kinesphere.services.databank.replies import DEFAULT_BUDGET, EncodedReply, entry_bytes
from kinesphere.zconfig import LOOPBACK_ANY_PORT, close_session, loopback_hub
from support.databank import Tokens, serve_process
from support.network import OWN_KEYS, peer
from support.soak import MIB, SCALE, FloodTally, mib, rss
from support.wait import WAIT_S

pytestmark = pytest.mark.processes

ARM = ("limb_11", "distal_11", "left-high")  # Baxter's right arm from the shoulder
BATCH = 16
OVERHEAD = 24 * MIB
"""Receiving 64 KiB payloads costs ~20 MiB of Zenoh buffers and allocator arenas (measured: a
plateau, the same after 500 or 4,000 such requests), plus the few MiB of pose answers the
CI-size flood legitimately caches."""
GROWTH_BOUND = DEFAULT_BUDGET.errors + DEFAULT_BUDGET.compounds + OVERHEAD
"""What the CI-size flood may add: the error and compound caches full, plus OVERHEAD. The
answer cache (32 MiB) cannot fill at this size; at soak size the bound adds it."""
WARM_FUZZ = 10
"""Fuzzed requests per warm-up round (500 in all): the valid ones alone left the allocator
short of its working size in a loaded full run (RSS 68.8 MiB before the flood, where alone it
was 95 MiB), so the growth measured was the warm-up's shortfall (47 MiB, after the same
115.6 MiB plateau as alone)."""
PLATEAU = 8 * MIB
"""What the second half of the flood may add to the first: bounded means it stops growing
(at soak size the answer cache is filled before the flood, so both halves see full caches)."""


def growth_bound() -> int:
    return GROWTH_BOUND + (DEFAULT_BUDGET.answers if SCALE > 1 else 0)


class Flood:
    """Pipelined queries (BATCH in flight) with every reply's outcome tallied."""

    def __init__(self, session: zenoh.Session, tally: FloodTally) -> None:
        self.session = session
        self.tally = tally
        self._pending: list[zenoh.Handler[zenoh.Reply]] = []

    def get(self, key: str, payload: bytes | None = None) -> None:
        self.tally.sent += 1
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
    replies = list(session.get(OWN_KEYS.pose("baxter", *ARM, 2), timeout=10.0))
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
        tokens = Tokens(client, OWN_KEYS)
        args = ["--prefix", OWN_KEYS.prefix, "--connect", endpoint, "--listen", LOOPBACK_ANY_PORT]
        try:
            with serve_process(args, "flood") as proc:
                assert tokens.wait("flood", timeout=60), "databank did not start"
                yield client, proc.pid
                assert proc.poll() is None, "the databank died during the flood"
                proc.terminate()
                _, err = proc.communicate(timeout=WAIT_S)
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
    tally = FloodTally("databank flood")
    flood = Flood(client, tally)
    for i in range(200):  # warm up: caches, Zenoh buffers, the allocator
        flood.get(OWN_KEYS.pose("baxter", *ARM, 1 + i / 200))
        flood.get(OWN_KEYS.compound("baxter"), compound(i, 1000))
    flood.drain()
    tally.sent, tally.codes = 0, type(tally.codes)()
    before = rss(pid)
    n = 3000 * SCALE
    if SCALE > 1:  # fill the answer cache first, so the flood's two halves compare full caches
        per_answer = entry_bytes(OWN_KEYS.pose("baxter", *ARM, 2.25),
                                 EncodedReply(True, zenoh.ZBytes(good)))
        fill = DEFAULT_BUDGET.answers // per_answer + 1
        for i in range(fill):  # sizes in [2, 2.5): none of the flood's own
            flood.get(OWN_KEYS.pose("baxter", *ARM, 2 + i / fill / 2))
        flood.drain()
        tally.sent, tally.codes = 0, type(tally.codes)()
    mid = before
    for i in range(n):
        if i == n // 2:
            flood.drain()
            mid = rss(pid)
        # a 30 KB unknown platform name: malformed (too long), never cached whole
        flood.get(f"{OWN_KEYS.prefix}/ecl/{i:08d}{'x' * 30_000}/catalogue")
        # an unknown platform with a legal name: unknown_platform, cached in the error cache
        flood.get(OWN_KEYS.catalogue(f"ghost-{i}-{'g' * 48}"))
        # a well-formed key for a new fractional size: a real answer each time
        flood.get(OWN_KEYS.pose("baxter", *ARM, 1 + i / n))
        if i % 3 == 0:  # 64 KiB compounds, each distinct
            flood.get(OWN_KEYS.compound("baxter"), compound(i, pr.MAX_PAYLOAD - 16))
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


def fuzz_request(rng: random.Random, valid: list[tuple[str, bytes | None]]
                 ) -> tuple[str, bytes | None]:
    """A valid request (key, payload) with its key or its payload mutated."""
    key, payload = rng.choice(valid)
    if payload is None or rng.random() < 0.3:
        head, _, tail = key.rpartition("/")
        segs = key.split("/")
        i = rng.randrange(2, len(segs))
        choices = ["", "x" * rng.randint(60, 200), segs[i] * 3, "**", "*", "$*", "@x",
                   "-1", "1e308", "nan", "3.5", "far", "Left High", "\u00e9t\u00e9",
                   tail[::-1], head[:3]]
        segs[i] = rng.choice(choices)
        return "/".join(s for s in segs if s != "" or rng.random() < 0.5), payload
    b = bytearray(payload)
    for _ in range(rng.randint(1, 6)):
        op = rng.randrange(3)
        i = rng.randrange(len(b))
        if op == 0:
            b[i] = rng.randrange(256)
        elif op == 1:
            del b[i:i + rng.randint(1, 8)]
        else:
            b[i:i] = rng.choice([b"\x91" * 3000 + b"\xc0", b"\xcf" + b"\xff" * 8,
                                 b"\xdd\xff\xff\xff\xff", rng.randbytes(rng.randint(1, 32))])
    return key, bytes(b)


def test_fuzzed_requests_get_named_errors_and_valid_ones_stay_exact(
    served: tuple[zenoh.Session, int],
) -> None:
    """Mutated keys and payloads of real requests: every reply is an answer or an Error with a
    known code, the databank neither dies nor logs a traceback, and valid answers never
    change (checked byte for byte every 500 requests)."""
    client, pid = served
    rng = random.Random(7)
    part = {"limb": "limb_11", "origin": "distal_11", "direction": "left-high", "size": 2}
    record = pr.RecordRequest(limb="limb_11", origin="distal_11", direction="left-high",
                              size=2, joints={"right_s0": 0.1})
    valid: list[tuple[str, bytes | None]] = [
        (OWN_KEYS.pose("baxter", *ARM, 2), None),
        (OWN_KEYS.pose("youbot", "limb_11", "distal_11", "forward-middle", 4.5), None),
        (OWN_KEYS.catalogue("nao"), None),
        (OWN_KEYS.compound("baxter"), msgspec.msgpack.encode(
            {"type": "compound_request", "parts": [part]})),
        (OWN_KEYS.record("baxter"), pr.encode(record)),  # writes are off: forbidden
    ]
    good = reference(client)
    tally = FloodTally("databank fuzz")
    flood = Flood(client, tally)
    warm = random.Random(8)  # fuzz of its own: the measured flood's requests stay the same
    for _ in range(50):  # warm up: caches, Zenoh buffers, the allocator
        for key, payload in valid:
            flood.get(key, payload)
        flood.get(OWN_KEYS.compound("baxter"), compound(rng.randrange(10**6), 1000))
        for _ in range(WARM_FUZZ):
            try:
                flood.get(*fuzz_request(warm, valid))
            except zenoh.ZError:
                pass
    flood.drain()
    tally.sent, tally.codes = 0, type(tally.codes)()
    before = rss(pid)
    n = 5000 * SCALE
    for i in range(n):
        key, payload = fuzz_request(rng, valid)
        try:
            flood.get(key, payload)
        except zenoh.ZError:  # a key Zenoh itself refuses never leaves the client
            tally.add("not a key expression")
        if i % 500 == 0:
            flood.drain()
            assert reference(client) == good
    flood.drain()
    after = rss(pid)
    tally.extra = {"RSS before": mib(before), "after": mib(after)}
    tally.report()
    known = {"ok", "no answer", "not a key expression", *ERROR_CODES} - {"internal"}
    assert set(tally.codes) <= known, tally.codes
    assert tally.codes["malformed"] > n // 4
    assert after - before < growth_bound()
