"""Key expressions: exact formats, Zenoh validity and matching, parsing, bad segments."""

from __future__ import annotations

import pytest
import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import KEYS, Keys, PoseKey, format_size

K = Keys()


def test_formats() -> None:
    assert K.pose("baxter", "limb_11", "distal_11", "left-high", 3) == (
        "kinesphere/ecl/baxter/pose/limb_11/distal_11/left-high/3"
    )
    assert K.pose_wildcard("nao") == "kinesphere/ecl/nao/pose/**"
    assert K.compound("nao") == "kinesphere/ecl/nao/compound"
    assert K.catalogue("nao") == "kinesphere/ecl/nao/catalogue"
    assert K.catalogue("*") == "kinesphere/ecl/*/catalogue"
    assert K.record("nao") == "kinesphere/ecl/nao/record"
    assert K.alive_databank("db1") == "kinesphere/alive/databank/db1"
    assert K.alive_databank_all() == "kinesphere/alive/databank/*"
    assert K.command("r1") == "kinesphere/robot/r1/command"
    assert K.command("*") == "kinesphere/robot/*/command"
    assert K.state("r1") == "kinesphere/robot/r1/state"
    assert K.alive_robot("r1") == "kinesphere/alive/robot/r1"
    assert K.group_command("arms") == "kinesphere/group/arms/command"
    assert KEYS == K


def test_custom_prefix() -> None:
    k = Keys("lab2/ks")
    assert k.command("r1") == "lab2/ks/robot/r1/command"
    assert k.pose("p", "l", "o", "d", 1) == "lab2/ks/ecl/p/pose/l/o/d/1"


@pytest.mark.parametrize(
    ("size", "text"),
    [(3, "3"), (3.0, "3"), (2.5, "2.5"), (0, "0"), (0.1, "0.1"), (12.25, "12.25")],
)
def test_size_is_compact(size: float, text: str) -> None:
    assert format_size(size) == text
    assert K.pose("p", "l", "o", "d", size).endswith("/" + text)


@pytest.mark.parametrize("size", [float("nan"), float("inf"), -1.0])
def test_bad_size_in_key(size: float) -> None:
    with pytest.raises(KinesphereError) as info:
        K.pose("p", "l", "o", "d", size)
    assert info.value.code == "size_out_of_range"


def test_keys_are_valid_zenoh_keys_and_match_their_wildcards() -> None:
    pose = K.pose("baxter", "limb_11", "distal_11", "left-high", 2.5)
    assert str(zenoh.KeyExpr(pose)) == pose  # already canonical
    assert zenoh.KeyExpr(K.pose_wildcard("baxter")).includes(pose)
    assert not zenoh.KeyExpr(K.pose_wildcard("nao")).includes(pose)
    assert zenoh.KeyExpr(K.pose_wildcard("*")).includes(pose)
    assert zenoh.KeyExpr(K.command("*")).includes(K.command("r1"))
    assert not zenoh.KeyExpr(K.command("*")).includes(K.state("r1"))
    assert zenoh.KeyExpr(K.alive_databank_all()).includes(K.alive_databank("replica-2"))
    assert zenoh.KeyExpr(K.catalogue("*")).includes(K.catalogue("youbot"))
    assert not zenoh.KeyExpr(K.pose_wildcard("baxter")).includes(K.catalogue("baxter"))


def test_parse_pose_key_round_trip() -> None:
    key = K.pose("baxter", "limb_11", "distal_11", "left-forward-high", 2.5)
    parsed = K.parse_pose_key(key)
    assert parsed == PoseKey("baxter", "limb_11", "distal_11", "left-forward-high", "2.5")
    platform, limb, origin, direction, size = parsed
    assert (platform, size) == ("baxter", "2.5")
    assert Keys("a/b").parse_pose_key("a/b/ecl/p/pose/l/o/d/far").size == "far"


@pytest.mark.parametrize(
    "key",
    [
        "kinesphere/ecl/baxter/pose/limb_11/distal_11/left-high",  # no size
        "kinesphere/ecl/baxter/pose/limb_11/distal_11/left-high/3/extra",
        "kinesphere/ecl/baxter/catalogue",
        "kinesphere/ecl/baxter/poses/limb_11/distal_11/left-high/3",
        "other/ecl/baxter/pose/limb_11/distal_11/left-high/3",
        "kinesphere/ecl/baxter/pose/limb_11//left-high/3",  # empty origin
        "kinesphere/ecl/baxter/pose/limb_11/*/left-high/3",  # wildcard origin
        "",
    ],
)
def test_parse_pose_key_rejects_wrong_shapes(key: str) -> None:
    with pytest.raises(KinesphereError) as info:
        K.parse_pose_key(key)
    assert info.value.code == "malformed"


@pytest.mark.parametrize("bad", ["", "a/b", "a*", "*", "$x", "what?", "x#1", "@r1"])
def test_bad_segments_are_malformed(bad: str) -> None:
    with pytest.raises(KinesphereError) as info:
        K.pose("baxter", bad, "o", "d", 1)
    assert info.value.code == "malformed"
    assert "limb" in info.value.message


@pytest.mark.parametrize("bad", ["", "a/b", "r*", "**", "$*", "@r"])
def test_bad_robot_ids(bad: str) -> None:
    for build in (K.command, K.state, K.alive_robot):
        with pytest.raises(KinesphereError) as info:
            build(bad)
        assert info.value.code == "malformed" and "robot id" in info.value.message


def test_wildcard_only_where_documented() -> None:
    assert K.alive_databank("*") == K.alive_databank_all()
    with pytest.raises(KinesphereError):
        K.group_command("*")
    with pytest.raises(KinesphereError):
        K.pose("*", "l", "o", "d", 1)


@pytest.mark.parametrize("prefix", ["", "a//b", "/a", "a/", "kin*", "@admin"])
def test_bad_prefix(prefix: str) -> None:
    with pytest.raises(KinesphereError) as info:
        Keys(prefix)
    assert info.value.code == "malformed"


def test_robot_id_and_replica_of_keys() -> None:
    assert K.robot_id_of(K.command("r1")) == "r1"
    assert K.robot_id_of(K.state("r-2")) == "r-2"
    assert K.robot_id_of(K.alive_robot("r3")) == "r3"
    assert Keys("x/y").robot_id_of("x/y/robot/r9/state") == "r9"
    assert K.replica_of(K.alive_databank("db1")) == "db1"
    for bad in ["kinesphere/robot/r1/pose", "other/robot/r1/state", "kinesphere/robot/r1"]:
        with pytest.raises(KinesphereError):
            K.robot_id_of(bad)
    for bad in ["kinesphere/alive/robot/r1", "kinesphere/alive/databank/a/b"]:
        with pytest.raises(KinesphereError):
            K.replica_of(bad)


def test_names_are_capped_and_not_echoed_whole() -> None:
    """A 30 KB name was echoed (and cached) whole by the databank's unknown_platform reply."""
    assert KEYS.command("r" * 64)
    for build in (KEYS.command, KEYS.catalogue, KEYS.alive_robot, KEYS.group_command):
        with pytest.raises(KinesphereError) as info:
            build("x" * 30_000)
        assert info.value.code == "malformed" and "30000 characters, at most 64" in str(
            info.value)
        assert len(info.value.message) < 200
    with pytest.raises(KinesphereError) as info:
        KEYS.parse_pose_key(f"kinesphere/ecl/baxter/pose/{'l' * 30_000}/o/d/1")
    assert len(info.value.message) < 300
