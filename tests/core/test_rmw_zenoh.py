"""rmw_zenoh's wire format: keys, graph tokens, QoS text, attachments, CDR bounds, a node.

Expected strings are written out literally from rmw_zenoh_cpp's rules (liveliness_utils.cpp,
qos.cpp, attachment_helpers.cpp), so a change in the code cannot move the expectation with it.
"""

from __future__ import annotations

import struct
import sys
import threading
from collections.abc import Callable

import pytest
import xxhash
import zenoh
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__String as String
from zenoh import ZBytes
from zenoh.ext import Int64, z_deserialize, z_serialize

from kinesphere import rmw_zenoh as rz
from kinesphere import ros2msgs, zconfig
from kinesphere.errors import KinesphereError
from kinesphere.ros2node import Node

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
"""std_msgs/msg/String in Jazzy, as ``ros2 topic info -v`` prints it."""
ZID = "1234567890abcdef1234567890abcdef"


def test_known_type_hash_pins_the_key_format() -> None:
    assert rz.type_hash("std_msgs/msg/String") == STRING_HASH
    assert rz.topic_key(0, "/chatter", "std_msgs/msg/String") == (
        f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    )
    assert rz.topic_key(5, "/robot/sensors/camera", "std_msgs/msg/String", any_hash=True) == (
        "5/robot/sensors/camera/std_msgs::msg::dds_::String_/*"
    )
    for t in (ros2msgs.JOINT_STATE, ros2msgs.TF_MESSAGE, ros2msgs.JOY,
              ros2msgs.JOINT_TRAJECTORY, ros2msgs.FLOAT64_MULTI_ARRAY):
        h = rz.type_hash(t)
        assert h.startswith("RIHS01_") and len(h) == 7 + 64 and h != STRING_HASH
    assert rz.dds_type_name("sensor_msgs/msg/JointState") == "sensor_msgs::msg::dds_::JointState_"


def test_graph_tokens_match_rmw_zenoh() -> None:
    assert rz.node_token(0, ZID, 3, "/", "talker") == f"@ros2_lv/0/{ZID}/3/3/NN/%/%/talker"
    assert rz.node_token(42, ZID, 5, "robot/arm", "n") == f"@ros2_lv/42/{ZID}/5/5/NN/%/%robot%arm/n"
    token = rz.endpoint_token(rz.EntityKind.PUBLISHER, 0, ZID, 3, 7, "/", "talker", "/chatter",
                              "std_msgs/msg/String", rz.Qos())
    assert token == (
        f"@ros2_lv/0/{ZID}/3/7/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
        f"{STRING_HASH}/::,10:,:,:,,"
    )
    sub = rz.endpoint_token(rz.EntityKind.SUBSCRIPTION, 1, ZID, 3, 8, "/ns", "listener",
                            "/ns/robot_description", "std_msgs/msg/String", rz.LATCHED)
    entity = rz.parse_token(sub)
    assert (entity.kind, entity.domain, entity.namespace, entity.node, entity.topic) == (
        rz.EntityKind.SUBSCRIPTION, 1, "/ns", "listener", "/ns/robot_description"
    )
    assert entity.qos == ":1:,1:,:,:,,"
    assert entity.dds_type == "std_msgs::msg::dds_::String_"
    with pytest.raises(KinesphereError, match="node name"):
        rz.node_token(0, ZID, 1, "/", "bad-name")
    with pytest.raises(KinesphereError, match="not a ROS graph token"):
        rz.parse_token("@ros2_lv/0/x/1")


def test_qos_text() -> None:
    assert rz.Qos().keyexpr() == "::,10:,:,:,,"
    assert rz.Qos(depth=42).keyexpr() == "::,:,:,:,,"
    assert rz.Qos(reliable=False, depth=1).keyexpr() == "2::,1:,:,:,,"
    assert rz.LATCHED.keyexpr() == ":1:,1:,:,:,,"
    with pytest.raises(KinesphereError):
        rz.Qos(depth=-1)


def test_attachment_is_zenoh_ext_serialisation() -> None:
    """rmw_zenoh (Jazzy >= 0.2.4) serialises (int64, int64, std::array<uint8_t, 16>) with
    zenoh-cpp, which writes the array as a sequence: zenoh-ext's own serialiser, with the gid
    as ``bytes`` (a sequence), must produce and read the very same 33 bytes."""
    gid = bytes(range(16))
    data = bytes(rz.Attachment(7, 1_700_000_000_123_456_789, gid).encode())
    assert len(data) == 33
    assert data == struct.pack("<qq", 7, 1_700_000_000_123_456_789) + b"\x10" + gid
    assert data == z_serialize((Int64(7), Int64(1_700_000_000_123_456_789), gid)).to_bytes()
    seq, ts, back_gid = z_deserialize(tuple[Int64, Int64, bytes], ZBytes(data))
    assert (seq, ts, back_gid) == (7, 1_700_000_000_123_456_789, gid)
    back = rz.Attachment.decode(data)
    assert (back.sequence_number, back.source_timestamp_ns, back.gid) == (
        7, 1_700_000_000_123_456_789, gid
    )
    pre_0_2_4 = data[:16] + data[17:]  # the gid as 16 loose bytes, as kinesphere once wrote
    for bad in (None, b"", b"x" * 31, pre_0_2_4, data + b"x", data[:16] + b"\x0f" + data[17:]):
        with pytest.raises(KinesphereError, match="attachment"):
            rz.Attachment.decode(bad)


def test_gid_is_rmw_zenoh_xxh3_of_the_token() -> None:
    token = rz.node_token(0, ZID, 1, "/", "n")
    digest = xxhash.xxh3_128(token.encode()).digest()  # canonical: high 64 bits first
    high, low = digest[:8], digest[8:]
    assert rz.gid_of(token) == low[::-1] + high[::-1]


def test_names() -> None:
    assert rz.ros_name("baxter-1") == "baxter_1"
    assert rz.ros_name("2nd.robot") == "_2nd_robot"
    assert rz.resolve("/", "joy") == "/joy"
    assert rz.resolve("/ns", "a/b") == "/ns/a/b"
    assert rz.resolve("/ns", "/abs") == "/abs"
    assert rz.check_namespace("arm") == "/arm"
    for bad in ("", "a//b", "1a", "a-b", "a/", "x" * 300):
        with pytest.raises(KinesphereError, match="ROS topic"):
            rz.resolve("/", bad)
    check_domain: Callable[..., int] = rz.check_domain  # as an untyped caller calls it
    for domain in (-1, 233, True, "0"):
        with pytest.raises(KinesphereError, match="domain"):
            check_domain(domain)
    with pytest.raises(KinesphereError, match="pkg/msg/Name"):
        rz.dds_type_name("JointState")
    with pytest.raises(KinesphereError, match="not in the Jazzy type store"):
        rz.type_hash("nope_msgs/msg/Nothing")


def test_cdr_round_trip_and_bounds() -> None:
    msg = ros2msgs.joint_state(["a", "b"], [0.5, -1.0], [0.1, 0.2], 1_500_000_000)
    data = rz.serialize(msg, ros2msgs.JOINT_STATE)
    assert data[:4] == b"\x00\x01\x00\x00"  # CDR little endian
    joints = ros2msgs.read_joint_state(rz.deserialize(data, ros2msgs.JOINT_STATE))
    assert joints == (("a", "b"), (0.5, -1.0), (0.1, 0.2), 1_500_000_000)
    with pytest.raises(KinesphereError, match="malformed|bad"):
        rz.deserialize(data[:-9], ros2msgs.JOINT_STATE)
    with pytest.raises(KinesphereError, match="limit"):
        rz.deserialize(data, ros2msgs.JOINT_STATE, max_bytes=len(data) - 1)
    # a sequence length far beyond the bound, claimed by a short message
    head = b"\x00\x01\x00\x00" + struct.pack("<II", 0, 0)  # encapsulation, stamp
    huge = head + struct.pack("<I", 1) + b"\x00" * 4 + struct.pack("<I", 10_000_000)
    with pytest.raises(KinesphereError, match="bad sensor_msgs/msg/JointState"):
        rz.deserialize(huge, ros2msgs.JOINT_STATE)
    bad = ros2msgs.joint_state(["a", "b"], [0.5], [], 0)
    with pytest.raises(KinesphereError, match="2 names, 1 positions"):
        ros2msgs.read_joint_state(rz.deserialize(rz.serialize(bad, ros2msgs.JOINT_STATE),
                                                 ros2msgs.JOINT_STATE))


def test_missing_extra_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    rz.typestore.cache_clear()
    monkeypatch.setitem(sys.modules, "rosbags", None)
    monkeypatch.setitem(sys.modules, "rosbags.typesys.store", None)
    try:
        with pytest.raises(KinesphereError, match=r"kinesphere\[ros2\]"):
            rz.typestore()
    finally:
        monkeypatch.undo()
        rz.typestore.cache_clear()
    assert rz.typestore() is rz.typestore()


def test_node_over_zenoh_announces_itself_and_round_trips() -> None:
    with zconfig.loopback_pair() as (a, b):
        node = Node(a, "talker", "/demo", domain=3)
        got: list[str] = []
        arrived = threading.Event()

        def on_msg(msg: String) -> None:
            got.append(msg.data)
            arrived.set()

        listener = Node(b, "listener", "/demo", domain=3)
        listener.subscription("chatter", ros2msgs.STRING, on_msg)
        pub = node.publisher("chatter", ros2msgs.STRING)
        assert pub.key == f"3/demo/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
        assert pub.matched()
        raw: list[zenoh.Sample] = []
        raw_arrived = threading.Event()

        def on_raw(sample: zenoh.Sample) -> None:
            raw.append(sample)
            raw_arrived.set()

        raw_sub = b.declare_subscriber(pub.key, on_raw)
        pub.put(ros2msgs.string("hello"))
        assert arrived.wait(5) and raw_arrived.wait(5)
        assert got == ["hello"]
        tokens = [str(r.ok.key_expr) for r in b.liveliness().get(rz.graph_wildcard(3), timeout=5)
                  if r.ok is not None]
        kinds = sorted((e.kind, e.node, e.topic) for e in map(rz.parse_token, tokens))
        assert kinds == [  # sorted by kind text: MP, MS, NN
            (rz.EntityKind.PUBLISHER, "talker", "/demo/chatter"),
            (rz.EntityKind.SUBSCRIPTION, "listener", "/demo/chatter"),
            (rz.EntityKind.NODE, "listener", ""), (rz.EntityKind.NODE, "talker", ""),
        ]
        pub_token = next(t for t in tokens if "/MP/" in t)
        att = rz.Attachment.decode(bytes(raw[0].attachment or b""))
        assert att.sequence_number == 1 and att.gid == rz.gid_of(pub_token)
        zconfig.undeclare(raw_sub)
        gone: set[str] = set()
        all_gone = threading.Event()

        def on_token(sample: zenoh.Sample) -> None:
            if sample.kind == zenoh.SampleKind.DELETE:
                gone.add(str(sample.key_expr))
                if gone >= set(tokens):
                    all_gone.set()

        watch = b.liveliness().declare_subscriber(rz.graph_wildcard(3), on_token)
        node.close()
        listener.close()
        assert all_gone.wait(5), set(tokens) - gone
        assert [r for r in b.liveliness().get(rz.graph_wildcard(3), timeout=2) if r.ok] == []
        zconfig.undeclare(watch)
