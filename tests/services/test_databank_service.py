"""The databank service in-process on real loopback sessions: every key, every bad input."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from pathlib import Path

import msgspec
import pytest
import zenoh

from kinesphere import protocol as pr
from kinesphere import zconfig
from kinesphere.errors import KinesphereError
from kinesphere.ratelog import RateLog
from kinesphere.services.databank.service import DatabankService, changed_key
from kinesphere.services.ecl.ecl import Ecl
from support.databank import (
    Tokens,
    answered,
    build_toy,
    error_code,
    pose_of,
    raw_get,
    serving,
)
from support.network import OWN_KEYS, peer
from support.paths import TOY

ARM = ("toyarm", "limb_11", "distal_11")


@pytest.fixture(scope="module")
def db(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_toy(tmp_path_factory.mktemp("db") / "toy.sqlite")


@pytest.fixture(scope="module")
def net(db: Path) -> Iterator[tuple[DatabankService, zenoh.Session]]:
    """A read-only replica serving toyarm (a subset of the known platforms) on the hub, and
    a querier joined to the hub."""
    with serving({"toyarm": Ecl.open(str(TOY), db)}, "solo") as (svc, client, _):
        yield svc, client


def pose_key(direction: str, size: str, limb: str = "limb_11", origin: str = "distal_11") -> str:
    return f"{OWN_KEYS.prefix}/ecl/toyarm/pose/{limb}/{origin}/{direction}/{size}"


# -- every key expression ------------------------------------------------------------------
def test_pose_queries(net: tuple[DatabankService, zenoh.Session]) -> None:
    svc, c = net
    stored = svc.ecl("toyarm").query("limb_11", "distal_11", "left-high", 2)
    pose = pose_of(raw_get(c, OWN_KEYS.pose(*ARM, "left-high", 2)))
    assert pose == stored and pose.p_id == 2 and pose.translation is None
    # aliases, spellings and named sizes are the ECL's; the reply is canonical
    alias = pose_of(raw_get(c, pose_key("Left_High", "mid", "arm", "shoulder")))
    assert (alias.limb, alias.origin, alias.direction, alias.joints) == (
        "limb_11", "distal_11", "left-high", stored.joints)
    half = pose_of(raw_get(c, pose_key("left-high", "2.5")))
    assert half.p_id is None and half.size == 2.5
    beyond = pose_of(raw_get(c, pose_key("left-high", "4")))
    assert beyond.translation is not None and math.isclose(beyond.translation[1], 0.1)
    core = pose_of(raw_get(c, OWN_KEYS.pose("toyarm", "c_1", "c_1", "forward-middle", 2)))
    assert core.joints == {} and core.translation == pytest.approx([0.2, 0.0, 0.0])


def test_compound_catalogue_record_and_liveliness(
    net: tuple[DatabankService, zenoh.Session],
) -> None:
    svc, c = net
    parts = [pr.SpatialCommand("limb_11", "distal_11", "left-high", 1),
             pr.SpatialCommand("limb_21", "distal_21", "left-middle", 2)]
    req = pr.encode(pr.CompoundRequest(parts=parts))
    pose = pose_of(raw_get(c, OWN_KEYS.compound("toyarm"), req))
    assert pose.is_compound and pose.joints == svc.ecl("toyarm").compound(parts).joints
    assert pose_of(raw_get(c, OWN_KEYS.compound("toyarm"), req)) == pose  # cached answer
    (ok, data), = raw_get(c, OWN_KEYS.catalogue("toyarm"))
    assert ok and pr.decode(data, pr.Catalogue) == svc.ecl("toyarm").catalogue()
    (ok, data), = raw_get(c, OWN_KEYS.catalogue("*"))  # discovery
    assert ok and pr.decode(data, pr.Catalogue).platform == "toyarm"
    record = pr.RecordRequest(limb="limb_11", origin="distal_11", direction="left-high",
                              size=1, joints={"yaw": 0.5})
    assert error_code(raw_get(c, OWN_KEYS.record("toyarm"), pr.encode(record))) == "forbidden"
    tokens = Tokens(c)
    try:
        assert tokens.wait("solo")
    finally:
        tokens.close()


def test_repeated_queries_come_from_the_reply_cache(
    net: tuple[DatabankService, zenoh.Session], monkeypatch: pytest.MonkeyPatch,
) -> None:
    svc, c = net
    key = OWN_KEYS.pose(*ARM, "right-low", 3)
    first = pose_of(raw_get(c, key))
    calls: list[object] = []
    ecl = svc.ecl("toyarm")
    monkeypatch.setattr(ecl, "query", lambda *a: calls.append(a))  # would break a lookup
    for _ in range(3):
        assert pose_of(raw_get(c, key)) == first
    assert calls == [] and key in [k for k in svc.answers._answers]


# -- bad input: the right code, and the service keeps serving -------------------------------
BAD_KEYS = [
    (f"{OWN_KEYS.prefix}/ecl/nosuchbot/pose/limb_11/distal_11/left-high/2", "unknown_platform"),
    (f"{OWN_KEYS.prefix}/ecl/nosuchbot/catalogue", "unknown_platform"),
    (pose_key("left-high", "2", limb="leg"), "unknown_limb"),
    (pose_key("left-high", "2", origin="distal_21"), "unknown_origin"),
    (pose_key("sideways", "2"), "unknown_direction"),
    (pose_key("back-low", "2"), "direction_unavailable"),
    (pose_key("left-high", "two"), "size_out_of_range"),
    (pose_key("left-high", "-1"), "size_out_of_range"),
    (pose_key("left-high", "nan"), "size_out_of_range"),
    (pose_key("left-high", "inf"), "size_out_of_range"),
    (pose_key("left-high", "1e999"), "size_out_of_range"),
    (f"{OWN_KEYS.prefix}/ecl/toyarm/pose/limb_11/distal_11", "malformed"),
    (f"{OWN_KEYS.prefix}/ecl/toyarm/pose/limb_11/distal_11/left-high/2/extra", "malformed"),
    (f"{OWN_KEYS.prefix}/ecl/toyarm/changed", "malformed"),
    (f"{OWN_KEYS.prefix}/ecl/toyarm/nonsense", "malformed"),
    (f"{OWN_KEYS.prefix}/ecl/toyarm/compound", "malformed"),  # no payload
]


@pytest.mark.parametrize(("key", "code"), BAD_KEYS)
def test_bad_keys(net: tuple[DatabankService, zenoh.Session], key: str, code: str) -> None:
    _, c = net
    assert error_code(raw_get(c, key)) == code
    assert error_code(raw_get(c, key)) == code  # the cached error is the same
    pose_of(raw_get(c, OWN_KEYS.pose(*ARM, "left-high", 1)))  # still serving


def _msg(**fields: object) -> bytes:
    return msgspec.msgpack.encode(fields)


PART = {"limb": "limb_11", "origin": "distal_11", "direction": "left-high", "size": 1}
BAD_COMPOUNDS = [
    (b"\xc1\xc1garbage", "malformed"),
    (b"\x00" * (pr.MAX_PAYLOAD + 1), "malformed"),
    (b"[1, 2, 3]", "malformed"),
    (msgspec.msgpack.encode([1, 2, 3]), "malformed"),
    (_msg(parts="limb_11"), "malformed"),
    (_msg(parts=[{**PART, "size": "big"}]), "malformed"),
    (_msg(parts=[{**PART, "size": float("nan")}]), "size_out_of_range"),
    (_msg(parts=[{**PART, "size": -2.0}]), "size_out_of_range"),
    (_msg(parts=[{**PART, "limb": ""}]), "malformed"),
    (_msg(parts=[]), "malformed"),
    (_msg(parts=[{**PART, "limb": "leg"}]), "unknown_limb"),
    (_msg(parts=[PART, {**PART, "direction": "right-low"}]), "conflict"),
    (_msg(type="pose", parts=[PART]), "malformed"),
    (_msg(v=2, parts=[PART]), "incompatible_version"),
    (b"\x82\xa5parts\x90\xa1x" + b"\x91" * 60_000 + b"\xc0", "malformed"),
    (_msg(v="1", parts=[PART]), "malformed"),
]


@pytest.mark.parametrize(
    ("payload", "code"), BAD_COMPOUNDS,
    ids=["garbage", "oversized", "json", "array", "parts-str", "size-str", "size-nan",
         "size-negative", "empty-limb", "no-parts", "unknown-limb", "conflict", "wrong-type",
         "version-2", "deep", "version-str"],
)
def test_bad_compound_payloads(
    net: tuple[DatabankService, zenoh.Session], payload: bytes, code: str
) -> None:
    _, c = net
    assert error_code(raw_get(c, OWN_KEYS.compound("toyarm"), payload)) == code
    pose_of(raw_get(c, OWN_KEYS.compound("toyarm"), _msg(parts=[PART])))  # still serving


def test_known_platform_served_elsewhere_gets_silence(
    net: tuple[DatabankService, zenoh.Session],
) -> None:
    """baxter is a shipped platform this replica does not serve: another replica may."""
    _, c = net
    assert raw_get(c, OWN_KEYS.pose("baxter", "limb_11", "distal_11", "left-high", 2)) == []
    assert raw_get(c, OWN_KEYS.catalogue("baxter")) == []


def test_unknown_platform_once_per_replica_serving_everything(db: Path) -> None:
    """Replicas that serve every known platform declare one complete queryable: any query,
    good or bad, is routed to exactly one of them."""
    with zconfig.loopback_hub() as (_hub, endpoint):
        sessions = [peer(endpoint) for _ in range(3)]
        services = [
            DatabankService(s, {"toyarm": Ecl.open(str(TOY), db)}, OWN_KEYS, f"r{i}",
                            known_platforms=()).start()
            for i, s in enumerate(sessions[:2])
        ]
        c = sessions[2]
        try:
            assert services[0].serves_all_known
            answered(c, OWN_KEYS.catalogue("toyarm"))
            for _ in range(20):
                assert len(raw_get(c, OWN_KEYS.pose(*ARM, "left-high", 2))) == 1
                assert error_code(raw_get(c, f"{OWN_KEYS.prefix}/ecl/nao/catalogue")) == (
                    "unknown_platform")
        finally:
            for svc in services:
                svc.close()
            for s in sessions:
                zconfig.close_session(s)


def test_construction_checks(db: Path) -> None:
    with zconfig.loopback_hub() as (hub, _):
        for ecls in ({}, {"x": Ecl.open(str(TOY), db)}):
            with pytest.raises(KinesphereError) as info:
                DatabankService(hub, ecls, OWN_KEYS)
            assert info.value.code == "malformed"
    assert changed_key(OWN_KEYS, "toyarm") == f"{OWN_KEYS.prefix}/ecl/toyarm/changed"


def test_malformed_requests_log_one_line_without_traceback(
    net: tuple[DatabankService, zenoh.Session], caplog: pytest.LogCaptureFixture
) -> None:
    """Before: deep nesting was ``internal`` with a full traceback logged per request."""
    svc, c = net
    svc.refused = RateLog(logging.getLogger("kinesphere.services.databank.service"))
    caplog.set_level(logging.DEBUG, logger="kinesphere")
    deep = b"\x82\xa5parts\x90\xa1x" + b"\x91" * 60_000 + b"\xc0"
    for _ in range(20):
        assert error_code(raw_get(c, OWN_KEYS.compound("toyarm"), deep)) == "malformed"
    lines = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(lines) == 1, [r.getMessage() for r in lines]
    assert lines[0].exc_info is None and "nested too deeply" in lines[0].getMessage()
    assert svc.refused.held == 19
