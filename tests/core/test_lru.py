"""The one bounded table: least recently used first out, by count and by bytes."""

from __future__ import annotations

import pytest

from kinesphere.lru import Lru


def test_past_most_the_least_recently_used_goes_first() -> None:
    table: Lru[str, int] = Lru(3)
    for i, key in enumerate("abc"):
        table.put(key, i)
    assert table.get("a") == 0  # a is now the most recently used
    table.put("d", 3)
    assert len(table) == 3 and "b" not in table and [table.get(k) for k in "acd"] == [0, 2, 3]
    table.put("c", 9)  # a new value for a kept key counts once
    assert len(table) == 3 and table.get("c") == 9


def test_past_max_bytes_the_least_recently_used_goes_first() -> None:
    table: Lru[str, bytes] = Lru(100, max_bytes=10, size=lambda k, v: len(v))
    table.put("a", b"1234")
    table.put("b", b"1234")
    assert table.bytes == 8
    table.get("a")
    table.put("c", b"12345")
    assert "b" not in table and table.bytes == 9 and table.get("a") == b"1234"
    table.put("a", b"1")
    assert table.bytes == 6
    assert table.put("huge", b"x" * 11) == b"x" * 11  # larger than the whole budget: not kept
    assert "huge" not in table and table.bytes == 6 and len(table) == 2


@pytest.mark.parametrize("most, max_bytes, sized, largest", [
    (0, 0, False, 0), (1, -1, False, 0), (1, 10, False, 0), (1, 0, False, 5), (1, 10, True, 11),
    (1, 10, True, -1)])
def test_bounds_are_checked(most: int, max_bytes: int, sized: bool, largest: int) -> None:
    with pytest.raises(ValueError):
        Lru(most, max_bytes, (lambda k, v: 1) if sized else None, largest=largest)


def test_an_entry_over_largest_is_not_kept_though_the_budget_holds_it() -> None:
    table: Lru[str, bytes] = Lru(100, max_bytes=12, size=lambda k, v: len(v), largest=3)
    table.put("a", b"123")
    table.put("b", b"1234")
    assert "a" in table and "b" not in table and table.bytes == 3


def test_peek_leaves_the_order_pop_and_clear_forget() -> None:
    table: Lru[str, int] = Lru(2)
    table.put("a", 1)
    table.put("b", 2)
    assert table.peek("a") == 1 and table.peek("z") is None
    table.put("c", 3)  # a was only peeked at: still the least recently used
    assert list(table) == ["b", "c"] and list(table.items()) == [("b", 2), ("c", 3)]
    assert table.pop("b") == 2 and table.pop("b") is None and list(table) == ["c"]
    sized: Lru[str, bytes] = Lru(4, max_bytes=10, size=lambda k, v: len(v))
    sized.put("a", b"1234")
    assert sized.pop("a") == b"1234" and sized.bytes == 0
    sized.put("b", b"12")
    sized.clear()
    assert len(sized) == 0 and sized.bytes == 0 and sized.get("b") is None
