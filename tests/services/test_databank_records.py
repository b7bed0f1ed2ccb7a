"""Super-user records: forbidden by default, served at once when enabled, announced on
``changed``, and followed by the other replicas."""

from __future__ import annotations

import shutil
import threading
from collections.abc import Iterator
from functools import partial
from pathlib import Path

import pytest
import zenoh

from kinesphere import protocol as pr
from kinesphere import zconfig
from kinesphere.services.databank.service import DatabankService, changed_key
from kinesphere.services.ecl.ecl import Ecl
from support.databank import answered, build_toy, error_code, pose_of, raw_get
from support.network import OWN_KEYS, peer
from support.paths import TOY
from support.wait import until

CELL = ("limb_11", "distal_11", "left-high")


def record_request(size: int = 2, **joints: float) -> bytes:
    return pr.encode(pr.RecordRequest(limb="arm", origin="shoulder", direction="Left High",
                                      size=size, joints=joints or {"yaw": 0.75}))


def _serves(svc: DatabankService, size: int, pose: pr.Pose) -> bool:
    """``svc`` answers the test's cell at ``size`` with ``pose``."""
    return svc.ecl("toyarm").query(*CELL, size) == pose


class Net:
    """A hub with replicas (in-process services on their own sessions) and a querier."""

    def __init__(self, endpoint: str) -> None:
        self.endpoint = endpoint
        self.client = peer(endpoint)
        self.services: list[DatabankService] = []
        self._sessions = [self.client]

    def replica(self, name: str, db: Path, writes: bool) -> DatabankService:
        s = peer(self.endpoint)
        self._sessions.append(s)
        svc = DatabankService(s, {"toyarm": Ecl.open(str(TOY), db)}, OWN_KEYS, name, writes).start()
        self.services.append(svc)
        answered(self.client, OWN_KEYS.catalogue("toyarm"))
        return svc

    def close(self) -> None:
        for svc in self.services:
            svc.close()
        for s in self._sessions:
            zconfig.close_session(s)


@pytest.fixture
def net() -> Iterator[Net]:
    with zconfig.loopback_hub() as (_hub, endpoint):
        n = Net(endpoint)
        try:
            yield n
        finally:
            n.close()


def test_record_is_forbidden_by_default_query_and_put(net: Net, tmp_path: Path) -> None:
    db = build_toy(tmp_path / "toy.sqlite")
    before = db.read_bytes()
    svc = net.replica("ro", db, writes=False)
    refused = raw_get(net.client, OWN_KEYS.record("toyarm"), record_request())
    assert error_code(refused) == "forbidden"
    net.client.put(OWN_KEYS.record("toyarm"), record_request())
    refused = raw_get(net.client, OWN_KEYS.record("toyarm"), record_request())
    assert error_code(refused) == "forbidden"
    assert db.read_bytes() == before
    assert svc.ecl("toyarm").query(*CELL, 2).joints["yaw"] != 0.75


def test_record_serves_new_values_at_once_and_announces_them(net: Net, tmp_path: Path) -> None:
    db = build_toy(tmp_path / "toy.sqlite")
    svc = net.replica("rw", db, writes=True)
    heard: list[zenoh.Sample] = []
    got = threading.Event()
    def on_change(sample: zenoh.Sample) -> None:
        heard.append(sample)
        got.set()

    sub = net.client.declare_subscriber(changed_key(OWN_KEYS, "toyarm"), on_change)
    key = OWN_KEYS.pose("toyarm", *CELL, 2)
    old = pose_of(raw_get(net.client, key))  # now cached; the subscriber is known by now
    version = svc.ecl("toyarm").version
    try:
        recorded = pose_of(raw_get(net.client, OWN_KEYS.record("toyarm"), record_request()))
        assert recorded.joints["yaw"] == 0.75 and recorded.p_id == 2
        assert recorded.joints["elbow"] == old.joints["elbow"]  # joints left out are kept
        new = pose_of(raw_get(net.client, key))
        assert new.joints == recorded.joints != old.joints
        assert svc.ecl("toyarm").version != version
        catalogue = pr.decode(raw_get(net.client, OWN_KEYS.catalogue("toyarm"))[0][1], pr.Catalogue)
        assert catalogue.version == svc.ecl("toyarm").version
        assert got.wait(10)
        assert pr.decode(heard[0].payload, pr.Pose) == recorded
        assert heard[0].attachment is not None and heard[0].attachment.to_bytes() == b"rw"
        # a put records too, with nobody to answer
        got.clear()
        net.client.put(OWN_KEYS.record("toyarm"), record_request(3, wrist=-0.5))
        assert got.wait(10)
        stored = pose_of(raw_get(net.client, OWN_KEYS.pose("toyarm", *CELL, 3)))
        assert stored.joints["wrist"] == -0.5
        assert Ecl.open(str(TOY), db).query(*CELL, 3).joints["wrist"] == -0.5  # on disk
    finally:
        zconfig.undeclare(sub)


@pytest.mark.parametrize(
    ("payload", "code"),
    [
        (b"\xc1junk", "malformed"),
        (b"\x00" * (pr.MAX_PAYLOAD + 1), "malformed"),
        (b"", "malformed"),
        (record_request(size=0), "size_out_of_range"),
        (record_request(size=4), "size_out_of_range"),  # not a VSAM size (1, 2, 3)
        (record_request(size=1_000_000), "size_out_of_range"),
        (record_request(size=2**64 - 1), "malformed"),
        (b"\x81\xa1x" + b"\x91" * 60_000 + b"\xc0", "malformed"),
        (record_request(yaw=99.0), "malformed"),
        (record_request(tail_joint=0.1), "malformed"),
        (pr.encode(pr.RecordRequest(limb="leg", origin="shoulder", direction="left-high",
                                    size=1, joints={"yaw": 0.1})), "unknown_limb"),
        (pr.encode(pr.RecordRequest(limb="arm", origin="shoulder", direction="place-middle",
                                    size=1, joints={"yaw": 0.1})), "forbidden"),
    ],
    ids=["garbage", "oversized", "empty", "size-0", "size-4", "size-1e6", "size-uint64", "deep",
         "out-of-limits", "foreign-joint", "unknown-limb", "place-middle"],
)
def test_bad_records(net: Net, tmp_path: Path, payload: bytes, code: str) -> None:
    db = build_toy(tmp_path / "toy.sqlite")
    before = db.read_bytes()
    net.replica("rw", db, writes=True)
    assert error_code(raw_get(net.client, OWN_KEYS.record("toyarm"), payload)) == code
    assert db.read_bytes() == before
    pose_of(raw_get(net.client, OWN_KEYS.pose("toyarm", *CELL, 1)))  # still serving


def test_replicas_follow_each_others_records(net: Net, tmp_path: Path) -> None:
    """Own files + writes: the peer re-applies. Shared file, read-only: the peer reloads."""
    own = build_toy(tmp_path / "a.sqlite")
    other = shutil.copy(own, tmp_path / "b.sqlite")
    a = net.replica("a", own, writes=True)
    b = net.replica("b", Path(other), writes=True)
    c = net.replica("c", own, writes=False)
    # the default target reaches one replica: a writer records, the others follow it
    replies = answered(net.client, OWN_KEYS.record("toyarm"), record_request(1, yaw=-0.4))
    if replies[0][0]:
        recorded = pose_of(replies)
        for svc in (a, b, c):
            until(partial(_serves, svc, 1, recorded), 10.0, f"replica {svc.replica_id} to follow")
    else:  # it reached the read-only replica
        assert error_code(replies) == "forbidden"
    # a record sent to every replica (as the docs say) is stored by each writer
    replies = raw_get(net.client, OWN_KEYS.record("toyarm"), record_request(3, yaw=-0.3),
                      target=zenoh.QueryTarget.ALL_COMPLETE)
    assert sorted(ok for ok, _ in replies) == [False, True, True]
    recorded = pr.decode(next(data for ok, data in replies if ok), pr.Pose)
    for svc in (a, b, c):
        until(partial(_serves, svc, 3, recorded), 10.0, f"replica {svc.replica_id} to follow")
    assert Ecl.open(str(TOY), other).query(*CELL, 3) == recorded
