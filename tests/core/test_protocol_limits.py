"""Decoding is bounded: depth, size, integers; every failure is a ``malformed`` KinesphereError."""

from __future__ import annotations

from typing import Any

import msgspec
import pytest

from kinesphere import protocol as pr
from kinesphere.errors import KinesphereError

TYPES: list[Any] = [*pr.MESSAGE_TYPES, pr.AnyMessage]
COMMAND = {"type": "command", "v": 1, "seq": 1, "sent_ns": 5, "deadman": True, "ttl_ms": 300}


def packed_map(fields: dict[str, bytes]) -> bytes:
    """A MessagePack map whose values are given already encoded (to nest by hand)."""
    assert len(fields) < 16
    out = bytes([0x80 | len(fields)])
    for name, value in fields.items():
        out += msgspec.msgpack.encode(name) + value
    return out


def nested(depth: int) -> bytes:
    """``depth`` one-element arrays around a nil: ``[[[...[nil]...]]]``."""
    return b"\x91" * depth + b"\xc0"


def code_of(data: bytes, type_: Any) -> tuple[str, str]:
    with pytest.raises(KinesphereError) as info:
        pr.decode(data, type_)
    return info.value.code, info.value.message


DEEP = {
    "unknown-field": lambda d: packed_map({**{k: msgspec.msgpack.encode(v)
                                              for k, v in COMMAND.items()}, "x": nested(d)}),
    "version": lambda d: packed_map({"type": msgspec.msgpack.encode("command"), "v": nested(d)}),
    "type-tag": lambda d: packed_map({"type": nested(d)}),
    "bare": nested,
}


@pytest.mark.parametrize("where", DEEP)
@pytest.mark.parametrize("type_", TYPES, ids=lambda t: getattr(t, "__name__", "any"))
def test_deep_nesting_is_malformed_not_a_recursion_error(where: str, type_: Any) -> None:
    """Before: RecursionError (a traceback per request in the databank, a Zenoh callback
    traceback in the agent). Up to the 64 KiB payload limit, at every depth."""
    for depth in (2_000, pr.MAX_PAYLOAD - 64):
        code, _ = code_of(DEEP[where](depth), type_)
        assert code == "malformed"


def test_moderate_nesting_in_an_unknown_field_is_ignored() -> None:
    """Newer peers may add nested fields; a sane depth is skipped like any unknown field."""
    data = packed_map({**{k: msgspec.msgpack.encode(v) for k, v in COMMAND.items()},
                       "future": nested(50)})
    assert pr.decode(data, pr.Command).seq == 1


@pytest.mark.parametrize("type_", TYPES, ids=lambda t: getattr(t, "__name__", "any"))
def test_oversized_payload_is_refused_unread(type_: Any) -> None:
    limit = pr.max_payload(type_)
    code, message = code_of(b"\xc1" * (limit + 1), type_)  # 0xc1 never decodes: size first
    assert code == "malformed" and f"{limit + 1} bytes exceeds {limit}" in message


def test_a_body_model_of_a_large_robot_fits() -> None:
    text = "<robot>" + " " * (pr.MAX_PAYLOAD + 1000) + "</robot>"
    body = pr.BodyModel(platform="big", eurdf=text, base_kind="fixed", neutral={}, version="1")
    assert pr.decode(pr.encode(body), pr.BodyModel) == body
    assert pr.max_payload(pr.Command) == pr.MAX_PAYLOAD < pr.max_payload(pr.BodyModel)


INTEGERS = [
    (pr.Pose, {"type": "pose", "platform": "p", "limb": "l", "origin": "o", "direction": "d",
               "size": 1.0, "joints": {}, "k_id": 1}, ["k_id", "p_id"]),
    (pr.RecordRequest, {"type": "record_request", "limb": "l", "origin": "o", "direction": "d",
                        "size": 1, "joints": {}}, ["size"]),
    (pr.Ack, {"type": "ack", "robot_id": "r", "sender": "s", "seq": 1, "stage": "accepted",
              "stamp_ns": 1}, ["seq", "stamp_ns"]),
    (pr.Command, COMMAND, ["seq", "sent_ns"]),
]


@pytest.mark.parametrize(("type_", "base", "fields"), INTEGERS, ids=lambda x: str(x)[:20])
def test_integers_beyond_int64_are_malformed(type_: Any, base: dict[str, Any],
                                             fields: list[str]) -> None:
    """Before: 2**64 - 1 decoded, and reached SQLite as an OverflowError (``internal``)."""
    for field in fields:
        code, message = code_of(msgspec.msgpack.encode({**base, field: 2**64 - 1}), type_)
        assert code == "malformed" and f"$.{field}" in message
        assert pr.decode(msgspec.msgpack.encode({**base, field: pr.MAX_INT}), type_)


def test_catalogue_sizes_are_int64() -> None:
    entry = {"limb": "l", "origin": "o", "directions": [], "sizes": [2**64 - 1]}
    cat = {"type": "catalogue", "platform": "p", "core": [], "limbs": [entry], "joints": [],
           "sizes": [1], "version": "x"}
    assert code_of(msgspec.msgpack.encode(cat), pr.Catalogue)[0] == "malformed"


@pytest.mark.parametrize("v", ["1", 1.5, [1]])
def test_a_mistyped_version_is_malformed_not_another_version(v: object) -> None:
    """Before: ``v: "1"`` read "protocol version '1', this peer speaks 1"."""
    code, message = code_of(msgspec.msgpack.encode({**COMMAND, "v": v}), pr.Command)
    assert code == "malformed" and "v must be the integer 1" in message


def test_a_boolean_version_is_malformed() -> None:
    code, message = code_of(msgspec.msgpack.encode({**COMMAND, "v": True}), pr.Command)
    assert code == "malformed" and "$.v" in message


def test_another_version_still_says_so() -> None:
    code, message = code_of(msgspec.msgpack.encode({**COMMAND, "v": 7}), pr.Command)
    assert code == "incompatible_version" and "version 7, this peer speaks 1" in message


def test_a_huge_type_tag_is_not_echoed_whole() -> None:
    code, message = code_of(msgspec.msgpack.encode({"type": "x" * 60_000}), pr.Command)
    assert code == "malformed" and len(message) < 200
