"""Wire protocol: round trips, the version rule and useful errors for bad payloads."""

from __future__ import annotations

import math
from typing import Any

import msgspec
import pytest

from kinesphere import protocol as pr
from kinesphere.errors import ERROR_CODES, KinesphereError
from support.protocol import SAMPLES, SPATIAL


def raw(obj: Any) -> bytes:
    return msgspec.msgpack.encode(obj)


def as_map(msg: pr.Message) -> dict[str, Any]:
    out = msgspec.msgpack.decode(pr.encode(msg))
    assert isinstance(out, dict)
    return out


def malformed(data: Any, type_: Any) -> str:
    with pytest.raises(KinesphereError) as info:
        pr.decode(data, type_)
    assert info.value.code == "malformed", info.value
    return info.value.message


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: type(m).__name__)
def test_round_trip(msg: pr.Message) -> None:
    data = pr.encode(msg)
    assert pr.decode(data, type(msg)) == msg
    assert pr.decode_any(data) == msg


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: type(m).__name__)
def test_encode_into_a_reused_buffer_makes_the_bytes_of_encode(msg: pr.Message) -> None:
    data = pr.encode(msg)
    buffer = bytearray(b"\xff" * (len(data) + 100))  # a longer message was there before
    assert pr.encode_into(msg, buffer) is buffer
    assert bytes(buffer) == data


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: type(m).__name__)
def test_wire_is_a_map_with_version_and_type(msg: pr.Message) -> None:
    assert type(msg).__struct_fields__[0] == "v"
    m = as_map(msg)
    assert m["v"] == pr.PROTOCOL_VERSION == 1
    assert m["type"] == type(msg).__struct_config__.tag
    assert set(type(msg).__struct_fields__) <= set(m)


def test_every_message_type_has_a_sample_and_a_distinct_tag() -> None:
    assert {type(m) for m in SAMPLES} == set(pr.MESSAGE_TYPES)
    tags = [t.__struct_config__.tag for t in pr.MESSAGE_TYPES]
    assert len(set(tags)) == len(tags)


def test_hand_written_map_decodes_without_type_or_v() -> None:
    """A peer written without kinesphere may send a plain map; unknown fields are ignored."""
    data = raw({"parts": [{"limb": "l", "origin": "o", "direction": "d", "size": 3}], "x": 1})
    req = pr.decode(data, pr.CompoundRequest)
    assert req.parts == [pr.SpatialCommand("l", "o", "d", 3.0)]
    assert req.v == pr.PROTOCOL_VERSION and req.last_wins is False


def test_zbytes_like_payload_is_accepted() -> None:
    class Payload:
        def __bytes__(self) -> bytes:
            return pr.encode(SAMPLES[5])

    assert pr.decode(Payload(), pr.Error) == SAMPLES[5]
    assert pr.decode(memoryview(pr.encode(SAMPLES[5])), pr.Error) == SAMPLES[5]


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: type(m).__name__)
def test_other_version_is_incompatible(msg: pr.Message) -> None:
    m = as_map(msg)
    m["v"] = 2
    with pytest.raises(KinesphereError) as info:
        pr.decode(raw(m), type(msg))
    assert info.value.code == "incompatible_version"
    assert "2" in info.value.message and type(msg).__name__ in info.value.message


def test_other_version_wins_over_field_errors() -> None:
    """A v2 peer may have changed field types: say so, not "malformed"."""
    with pytest.raises(KinesphereError) as info:
        pr.decode(raw({"v": 2, "platform": ["changed"]}), pr.Pose)
    assert info.value.code == "incompatible_version"


def test_garbage_bytes_are_malformed() -> None:
    assert "not MessagePack" in malformed(b"\xc1\xff\x00", pr.Pose)
    assert "empty payload" in malformed(b"", pr.Command)


def test_wrong_field_type_names_the_field() -> None:
    m = as_map(SAMPLES[0])
    m["size"] = "far"
    msg = malformed(raw(m), pr.Pose)
    assert "$.size" in msg and "float" in msg and "Pose" in msg


def test_nested_wrong_type_names_the_path() -> None:
    m = as_map(SAMPLES[3])
    m["parts"][0]["limb"] = 5
    assert "$.parts[0].limb" in malformed(raw(m), pr.Command)


def test_missing_field_is_named() -> None:
    m = as_map(SAMPLES[4])
    del m["joint_names"]
    assert "joint_names" in malformed(raw(m), pr.RobotState)


def test_not_a_map_is_malformed() -> None:
    assert "Pose" in malformed(raw([1, 2, 3]), pr.Pose)


def test_wrong_message_type_is_named() -> None:
    msg = malformed(pr.encode(SAMPLES[0]), pr.Command)
    assert "'command'" in msg and "'pose'" in msg


def test_decode_any_rejects_unknown_type() -> None:
    with pytest.raises(KinesphereError) as info:
        pr.decode_any(raw({"type": "teleport"}))
    assert info.value.code == "malformed" and "teleport" in info.value.message


@pytest.mark.parametrize("speed", [1.5, -0.1, float("nan")])
def test_drive_speed_outside_0_1_is_malformed(speed: float) -> None:
    m = as_map(SAMPLES[3])
    m["drive"]["speed"] = speed
    assert "speed" in malformed(raw(m), pr.Command)


@pytest.mark.parametrize("field", ["seq", "ttl_ms"])
def test_negative_counters_are_malformed(field: str) -> None:
    m = as_map(SAMPLES[3])
    m[field] = -1
    assert field in malformed(raw(m), pr.Command)


def test_translation_must_have_three_components() -> None:
    m = as_map(SAMPLES[0])
    m["translation"] = [0.1, 0.2]
    assert "translation" in malformed(raw(m), pr.Pose)


def test_state_lengths_must_match_joint_names() -> None:
    m = as_map(SAMPLES[4])
    m["q"] = [0.1]
    assert "q has 1 values for 2 joint_names" in malformed(raw(m), pr.RobotState)
    m = as_map(SAMPLES[4])
    m["qd"] = []  # unknown velocities are allowed
    assert pr.decode(raw(m), pr.RobotState).qd == []
    with pytest.raises(ValueError):
        pr.RobotState(
            robot_id="r",
            platform="p",
            seq=0,
            stamp_ns=0,
            joint_names=["a"],
            q=[],
            qd=[],
            base_pose=[0.0, 0.0, 0.0],
            status=pr.Status.IDLE,
            last_command_seq=-1,
        )


def test_catalogue_that_translates_needs_a_step() -> None:
    m = as_map(SAMPLES[2])
    m["translation_step"] = None
    assert "translation_step" in malformed(raw(m), pr.Catalogue)


def test_statuses() -> None:
    assert pr.STATUSES == {
        "idle",
        "moving",
        "holding",
        "stopped",
        "estop",
        "clamped",
        "databank_unreachable",
        "error",
    }


@pytest.mark.parametrize("size", [float("nan"), float("inf"), -0.5])
def test_check_size_rejects(size: float) -> None:
    with pytest.raises(KinesphereError) as info:
        pr.check_size(size)
    assert info.value.code == "size_out_of_range"


def test_check_size_accepts_finite_non_negative() -> None:
    assert pr.check_size(0) == 0.0
    assert pr.check_size(2.5) == 2.5
    assert pr.check_spatial(SPATIAL) is SPATIAL


def test_check_spatial() -> None:
    with pytest.raises(KinesphereError) as info:
        pr.check_spatial(pr.SpatialCommand("limb", " ", "left-high", 1))
    assert info.value.code == "malformed" and "origin" in info.value.message
    with pytest.raises(KinesphereError) as info:
        pr.check_spatial(pr.SpatialCommand("limb", "o", "left-high", math.nan))
    assert info.value.code == "size_out_of_range"


def test_error_to_and_from_exception() -> None:
    exc = KinesphereError("forbidden", "writes are disabled")
    err = pr.Error.from_exception(exc)
    assert (err.code, err.message) == ("forbidden", "writes are disabled")
    back = pr.decode(pr.encode(err), pr.Error).to_exception()
    assert (back.code, back.message) == ("forbidden", "writes are disabled")
    newer = pr.Error(code="some_future_code", message="m").to_exception()
    assert newer.code == "internal" and "some_future_code" in newer.message
    assert {"malformed", "incompatible_version", "forbidden"} <= ERROR_CODES


def test_error_from_reply() -> None:
    exc = pr.error_from_reply(pr.encode(pr.Error(code="conflict", message="two parts")))
    assert (exc.code, exc.message) == ("conflict", "two parts")
    timeout = pr.error_from_reply(b"Timeout")  # what Zenoh itself sends on a query timeout
    assert (timeout.code, timeout.message) == ("unavailable", "Timeout")
    newer = pr.error_from_reply(raw({"v": 9, "code": "x", "message": "y"}))
    assert newer.code == "incompatible_version"


# --- bounds and compatibility of the fields added after the first release -----------------------


def test_version_1_peers_still_decode() -> None:
    """Messages as a version-1 peer sends them (no session, lease, drive vector) still decode."""
    cmd = pr.decode(raw({"type": "command", "v": 1, "seq": 1, "sent_ns": 5, "deadman": True,
                         "ttl_ms": 300, "drive": {"direction": "forward-middle", "speed": 0.5}}),
                    pr.Command)
    assert cmd.session == "" and cmd.lease is pr.LeaseAction.NONE
    assert cmd.drive is not None and not cmd.drive.is_continuous
    pose = pr.decode(raw({"type": "pose", "platform": "nao", "limb": "l", "origin": "o",
                          "direction": "d", "size": 1.0, "joints": {}, "k_id": 3}), pr.Pose)
    assert pose.substitutions == []


@pytest.mark.parametrize(
    ("fields", "what"),
    [
        ({"sender": "x" * (pr.MAX_NAME + 1)}, "sender"),
        ({"session": "s" * (pr.MAX_NAME + 1)}, "session"),
        ({"seq": -1}, "seq"),
        ({"ttl_ms": pr.MAX_TTL_MS + 1}, "ttl_ms"),
        ({"lease": "steal"}, "lease"),
        ({"drive": {"forward": 1.5}}, "forward"),
        ({"parts": [{"limb": "a", "origin": "b", "direction": "c", "size": 1}] * 17}, "parts"),
        ({"parts": [{"limb": "a" * 65, "origin": "b", "direction": "c", "size": 1}]}, "limb"),
    ],
)
def test_command_fields_are_bounded(fields: dict[str, Any], what: str) -> None:
    msg = {"type": "command", "seq": 1, "sent_ns": 5, "deadman": True, "ttl_ms": 300, **fields}
    assert what in malformed(raw(msg), pr.Command)


def test_joint_maps_are_bounded() -> None:
    joints = {f"j{i}": 0.0 for i in range(pr.MAX_JOINTS + 1)}
    msg = {"type": "record_request", "limb": "l", "origin": "o", "direction": "d", "size": 1,
           "joints": joints}
    assert "joints" in malformed(raw(msg), pr.RecordRequest)


def test_drive_continuous_form() -> None:
    assert pr.Drive(yaw=0.2).is_continuous
    assert not pr.Drive("left-middle", 1.0).is_continuous


def test_statuses_and_stages_are_plain_strings_on_the_wire() -> None:
    assert pr.STATUSES == {"idle", "moving", "holding", "stopped", "estop", "clamped",
                           "databank_unreachable", "error"}
    m = as_map(next(m for m in SAMPLES if isinstance(m, pr.Ack)))
    assert m["stage"] == "rejected" and type(m["stage"]) is str


@pytest.mark.parametrize(
    ("fields", "what"),
    [
        ({"robot_id": "r" * (pr.MAX_NAME + 1)}, "robot_id"),
        ({"joint_names": [f"j{i}" for i in range(pr.MAX_JOINTS + 1)],
          "q": [0.0] * (pr.MAX_JOINTS + 1), "qd": []}, "joint_names"),
        ({"detail": "d" * (pr.MAX_TEXT + 1)}, "detail"),
        ({"groups": [f"g{i}" for i in range(pr.MAX_PARTS + 1)]}, "groups"),
        ({"lease_holder": "h" * (pr.MAX_NAME + 1)}, "lease_holder"),
    ],
)
def test_robot_state_fields_are_bounded(fields: dict[str, Any], what: str) -> None:
    """A state from the wire is as bounded as a command: names, joint lists, free text."""
    ok = {"type": "robot_state", "robot_id": "r", "platform": "p", "seq": 1, "stamp_ns": 1,
          "joint_names": ["a"], "q": [0.0], "qd": [0.0], "base_pose": [0.0, 0.0, 0.0],
          "status": "idle", "last_command_seq": -1}
    assert pr.decode(raw(ok), pr.RobotState).robot_id == "r"
    assert what in malformed(raw({**ok, **fields}), pr.RobotState)


@pytest.mark.parametrize("angle", [-0.5, 180.5, float("nan"), "far"])
def test_an_acks_measured_angle_is_degrees_or_nothing(angle: object) -> None:
    """What the robot says its pose points away from the request: 0 to 180 degrees, absent
    from a robot that did not measure it (or an older one)."""
    ok = {"type": "ack", "robot_id": "r", "sender": "s", "seq": 1, "stage": "accepted",
          "stamp_ns": 1}
    assert pr.decode(raw(ok), pr.Ack).measured_angle is None
    assert pr.decode(raw({**ok, "measured_angle": 38.2}), pr.Ack).measured_angle == 38.2
    assert "measured_angle" in malformed(raw({**ok, "measured_angle": angle}), pr.Ack)
