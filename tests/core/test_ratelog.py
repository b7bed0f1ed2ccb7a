"""RateLog: one line per key per interval, repeats counted, keys bounded."""

from __future__ import annotations

import logging

import pytest

from kinesphere.ratelog import RateLog
from support.clock import ManualClock


def test_repeats_are_counted_into_the_next_line(caplog: pytest.LogCaptureFixture) -> None:
    clock = ManualClock()
    rl = RateLog(logging.getLogger("t.ratelog"), every=10.0, clock=clock)
    caplog.set_level(logging.INFO, logger="t.ratelog")
    assert rl("a", "denied %s", "x")
    assert not any(rl("a", "denied %s", "x") for _ in range(5))
    assert rl("b", "other")
    clock.now = 10.0
    assert rl("a", "denied %s", "x")
    assert [r.getMessage() for r in caplog.records] == [
        "denied x", "other", "denied x (+5 more in 10 s)"]
    assert rl.held == 5


def test_keys_are_bounded_oldest_first() -> None:
    clock = ManualClock()
    rl = RateLog(logging.getLogger("t.ratelog"), max_keys=100, clock=clock)
    for i in range(10_000):
        rl(f"key-{i}", "x")
    assert len(rl) == 100
    assert rl("key-0", "x")  # forgotten, so logged again
    assert not rl("key-9999", "x")  # still remembered


def test_a_burst_per_key_then_a_count(caplog: pytest.LogCaptureFixture) -> None:
    clock = ManualClock()
    rl = RateLog(logging.getLogger("t.ratelog"), every=10.0, burst=3, clock=clock)
    caplog.set_level(logging.INFO, logger="t.ratelog")
    logged = [rl("who", "line %d", i) for i in range(100)]
    assert logged == [True] * 3 + [False] * 97
    clock.now = 10.0
    assert rl("who", "again")
    assert caplog.records[-1].getMessage() == "again (+97 more in 10 s)"
