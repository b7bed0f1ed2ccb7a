"""Fuzzing the decoder: mutated, truncated, spliced and hand-nested payloads of every message.

Whatever the bytes, :func:`kinesphere.protocol.decode` returns a message or raises a
``KinesphereError`` with a known code; nothing else escapes (before: RecursionError on deep
nesting, and integers past int64 decoded). Seeded, so a failure replays.
"""

from __future__ import annotations

import random
import time
from collections import Counter
from typing import Any

from kinesphere import protocol as pr
from kinesphere.errors import ERROR_CODES, KinesphereError
from support.protocol import SAMPLES
from support.soak import SCALE, FloodTally

N = 20_000 * SCALE
TYPES: list[Any] = [*pr.MESSAGE_TYPES, pr.AnyMessage]


def mutate(rng: random.Random, data: bytes, pool: list[bytes]) -> bytes:
    """One of: flip bytes, truncate, splice another sample in, repeat a slice, nest deep."""
    b = bytearray(data)
    kind = rng.randrange(6)
    if kind == 0:
        for _ in range(rng.randint(1, 4)):
            b[rng.randrange(len(b))] = rng.randrange(256)
    elif kind == 1:
        del b[rng.randrange(len(b)):]
    elif kind == 2:
        other = rng.choice(pool)
        cut = rng.randrange(len(b))
        b[cut:] = other[rng.randrange(len(other)):]
    elif kind == 3:
        i = rng.randrange(len(b))
        b[i:i] = b[i:i + rng.randint(1, 16)] * rng.randint(1, 200)
    elif kind == 4:  # a value replaced by deep nesting
        i = rng.randrange(len(b))
        b[i:i + 1] = b"\x91" * rng.randint(100, 5000) + b"\xc0"
    else:  # an integer field replaced by a uint64 or a float
        i = rng.randrange(len(b))
        b[i:i + 1] = rng.choice([b"\xcf" + b"\xff" * 8, b"\xcb" + rng.randbytes(8),
                                 b"\xd3\x80" + b"\x00" * 7])
    return bytes(b)


def test_decode_never_raises_anything_but_a_kinesphere_error() -> None:
    rng = random.Random(12)
    pool = [pr.encode(m) for m in SAMPLES]
    tally = FloodTally("protocol fuzz")
    decoded: Counter[str] = Counter()
    start = time.perf_counter()
    for _ in range(N):
        data = mutate(rng, rng.choice(pool), pool)
        type_ = rng.choice(TYPES)
        tally.sent += 1
        try:
            msg = pr.decode(data, type_)
        except KinesphereError as exc:
            assert exc.code in ERROR_CODES
            tally.add(exc.code)
            continue
        # whatever decodes is a well-formed message that round-trips (bytes: NaN != NaN)
        again = pr.encode(msg)
        assert pr.encode(pr.decode(again, type(msg))) == again
        decoded[type(msg).__name__] += 1
        tally.add("decoded")
    tally.extra = {"decoded by type": dict(decoded),
                   "seconds": f"{time.perf_counter() - start:.1f}"}
    tally.report()
    assert tally.sent == N and tally.codes["malformed"] > N // 2
