"""The databank's reply caches are bounded in bytes, least recently used out first."""

from __future__ import annotations

import gc
import threading

import msgspec
import psutil
import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from kinesphere.services.databank.replies import (
    DEFAULT_BUDGET,
    ENTRY_BYTES,
    EncodedReply,
    ReplyCache,
    entry_bytes,
    err,
    ok,
)
from kinesphere.services.databank.worker import MAX_JOBS, Worker
from kinesphere.services.ecl.ecl import Ecl


def answer(n: int) -> EncodedReply:
    return EncodedReply(True, zenoh.ZBytes(b"p" * n))


def test_entries_are_charged_by_key_and_payload_bytes() -> None:
    assert entry_bytes("k" * 100, answer(50)) == ENTRY_BYTES + 150
    assert entry_bytes(("k" * 10, b"r" * 1000), answer(50)) == ENTRY_BYTES + 1060


def test_bounded_by_bytes_least_recently_used_first() -> None:
    cache = ReplyCache(max_bytes=10 * (ENTRY_BYTES + 1000 + 1))
    for i in range(10):
        cache.put(str(i), answer(1000), cache.generation)
    assert len(cache) == 10 and cache.bytes <= cache.max_bytes
    assert cache.get("0") is not None  # used: now the most recent
    for i in range(10, 15):
        cache.put(str(i), answer(1000), cache.generation)
    assert cache.bytes <= cache.max_bytes
    assert cache.get("0") is not None and cache.get("1") is None and cache.get("14") is not None
    # a flood of invented keys never holds more than the budget, whatever their size
    for i in range(10_000):
        cache.put("x" * (i % 3000) + str(i), answer(i % 500), cache.generation)
        assert cache.bytes <= cache.max_bytes


def test_a_full_cache_costs_the_process_no_more_than_its_budget() -> None:
    """The charge per entry is what an entry really costs (key and payload objects, the
    ZBytes, the dict slot and LRU link): a cache filled with real pose answers from the shipped
    Baxter databank, past the service's own answer budget, grows the process's RSS by at most
    that budget. Before, 256 bytes per entry undercounted: 35.4 MiB for 32 MiB charged."""
    keys = Keys()
    pose = Ecl.open("baxter").query("limb_11", "distal_11", "left-high", 2.0, False)
    budget = DEFAULT_BUDGET.answers
    cache = ReplyCache(budget)
    per_entry = entry_bytes(keys.pose("baxter", "limb_11", "distal_11", "left-high", 1.5),
                            ok(pose))
    n = budget * 13 // 10 // per_entry  # past the budget, so eviction runs too
    gc.collect()
    before = psutil.Process().memory_info().rss
    for i in range(n):
        size = 1.0 + i / n
        cache.put(keys.pose("baxter", "limb_11", "distal_11", "left-high", size),
                  ok(msgspec.structs.replace(pose, size=size)), cache.generation)
    gc.collect()
    grown = psutil.Process().memory_info().rss - before
    assert cache.bytes <= budget and len(cache) < n
    assert grown <= budget, f"{grown / 2**20:.1f} MiB for a {budget >> 20} MiB cache"


def test_an_answer_over_a_quarter_of_the_budget_is_not_cached() -> None:
    cache = ReplyCache(max_bytes=4000)
    kept = cache.put("k", answer(2000), cache.generation)
    assert kept.ok and cache.get("k") is None and cache.bytes == 0


def test_stale_generation_is_not_stored_and_invalidate_empties() -> None:
    cache = ReplyCache(max_bytes=1 << 20)
    g = cache.generation
    cache.put("a", err(KinesphereError("malformed", "x")), g)
    cache.invalidate()
    cache.put("b", answer(1), g)  # computed before the invalidation: dropped
    assert len(cache) == 0 and cache.bytes == 0


def test_worker_queue_is_bounded() -> None:
    worker = Worker("test-worker")
    release = threading.Event()
    started = threading.Event()

    def block() -> None:
        started.set()
        release.wait(10)

    worker.start()
    assert worker.submit(block) and started.wait(10)
    accepted = sum(worker.submit(lambda: None) for _ in range(MAX_JOBS + 50))
    assert accepted == MAX_JOBS
    release.set()
    worker.stop()
