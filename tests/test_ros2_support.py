"""The ROS 2 side of the ROS 2 tests, written without kinesphere's rmw_zenoh code.

ROS is not installed here; what stands in for it speaks rmw_zenoh's wire format on its own:
keys and graph tokens are written out with f-strings from rmw_zenoh_cpp's rules, CDR and type
hashes come from a separate rosbags type store, attachments are made and read with zenoh-ext's
serialiser. So a test passes only if kinesphere's implementation and this independent one
agree. Waits are on events (a message arriving), never on sleeps.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh
from rosbags.typesys import Stores, get_typestore
from zenoh.ext import Int64, UInt8, z_deserialize, z_serialize

from kinesphere import zconfig

JAZZY = get_typestore(Stores.ROS2_JAZZY)
WAIT_S = 30.0
"""Upper bound for events on a loaded 2-core machine; tests finish far sooner."""
GID = tuple[(UInt8,) * 16]  # type: ignore[misc]


def dds(ros_type: str) -> str:
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def key(domain: int, topic: str, ros_type: str) -> str:
    """rmw_zenoh's data key: ``<domain>/<topic without leading slash>/<dds type>/<hash>``."""
    return f"{domain}/{topic.strip('/')}/{dds(ros_type)}/{JAZZY.hash_rihs01(ros_type)}"


def attachment(seq: int, gid: bytes) -> zenoh.ZBytes:
    return z_serialize((Int64(seq), Int64(time.time_ns()), tuple(UInt8(b) for b in gid)))


def read_attachment(sample: zenoh.Sample) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp ns, gid); raises if absent or garbled."""
    assert sample.attachment is not None, "rmw_zenoh subscribers drop samples without one"
    seq, ts, gid = z_deserialize(tuple[Int64, Int64, GID], sample.attachment)  # type: ignore[misc]
    return int(seq), int(ts), bytes(gid)


def graph(session: zenoh.Session, domain: int) -> list[str]:
    """Every ROS graph token of ``domain`` now (what ``ros2 topic list`` is made of)."""
    return sorted(str(r.ok.key_expr) for r in
                  session.liveliness().get(f"@ros2_lv/{domain}/**", timeout=5.0)
                  if r.ok is not None)


class GraphWatch:
    """The live graph tokens of a domain, kept up to date, with waits on predicates."""

    def __init__(self, session: zenoh.Session, domain: int) -> None:
        self.tokens: set[str] = set()
        self._cond = threading.Condition()
        self._sub = session.liveliness().declare_subscriber(
            f"@ros2_lv/{domain}/**", self._on, history=True
        )

    def _on(self, sample: zenoh.Sample) -> None:
        with self._cond:
            if sample.kind == zenoh.SampleKind.PUT:
                self.tokens.add(str(sample.key_expr))
            else:
                self.tokens.discard(str(sample.key_expr))
            self._cond.notify_all()

    def wait(self, pred: Callable[[set[str]], bool], what: str,
             timeout: float = WAIT_S) -> set[str]:
        with self._cond:
            if not self._cond.wait_for(lambda: pred(self.tokens), timeout):
                raise AssertionError(f"graph never showed {what}: {sorted(self.tokens)}")
            return set(self.tokens)

    def close(self) -> None:
        zconfig.undeclare(self._sub)


@dataclass
class Received:
    msg: Any
    seq: int
    stamp_ns: int
    gid: bytes
    at: float


class RosTap:
    """Every message on one ROS topic, decoded with rosbags, attachment checked."""

    def __init__(self, session: zenoh.Session, domain: int, topic: str, ros_type: str,
                 history: bool = False) -> None:
        self.ros_type = ros_type
        self.key = key(domain, topic, ros_type)
        self.got: list[Received] = []
        self._cond = threading.Condition()
        if history:  # what rmw_zenoh does for a transient-local subscription
            self._sub: Any = zenoh.ext.declare_advanced_subscriber(
                session, self.key, self._on,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
                subscriber_detection=True,
            )
        else:
            self._sub = session.declare_subscriber(self.key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        seq, ts, gid = read_attachment(sample)
        msg = JAZZY.deserialize_cdr(sample.payload.to_bytes(), self.ros_type)
        with self._cond:
            self.got.append(Received(msg, seq, ts, gid, time.monotonic()))
            self._cond.notify_all()

    def wait(self, pred: Callable[[Any], bool] = lambda m: True, what: str = "a message",
             timeout: float = WAIT_S) -> Received:
        """The first message (from the start) that satisfies ``pred``."""
        deadline = time.monotonic() + timeout
        seen = 0
        with self._cond:
            while True:
                for r in self.got[seen:]:
                    if pred(r.msg):
                        return r
                seen = len(self.got)
                left = deadline - time.monotonic()
                if left <= 0 or not self._cond.wait(left):
                    raise AssertionError(f"no {what} on {self.key} within {timeout} s "
                                         f"({len(self.got)} other messages)")

    def close(self) -> None:
        zconfig.undeclare(self._sub)


class RosPublisher:
    """A ROS publisher in rmw_zenoh's format: data key, attachment, ``MP`` graph token."""

    def __init__(self, session: zenoh.Session, domain: int, topic: str, ros_type: str,
                 node: str = "stand_in", node_id: int = 900, entity_id: int = 901) -> None:
        self.ros_type = ros_type
        self.pub = session.declare_publisher(key(domain, topic, ros_type))
        zid = str(session.info.zid())
        mangled = topic.replace("/", "%")
        self.token = session.liveliness().declare_token(
            f"@ros2_lv/{domain}/{zid}/{node_id}/{entity_id}/MP/%/%/{node}/{mangled}/"
            f"{dds(ros_type)}/{JAZZY.hash_rihs01(ros_type)}/::,10:,:,:,,"
        )
        self.gid = bytes(range(16))
        self.seq = 0

    def put(self, msg: Any) -> None:
        self.seq += 1
        payload = bytes(JAZZY.serialize_cdr(msg, self.ros_type, little_endian=True))
        self.pub.put(payload, attachment=attachment(self.seq, self.gid))

    def close(self) -> None:
        zconfig.undeclare(self.token, self.pub)
