"""A ROS 2 node made of plain Zenoh entities, in the format of :mod:`kinesphere.rmw_zenoh`.

What ``rclcpp`` does over rmw_zenoh, reduced to what kinesphere needs: a node announces
itself with a graph token (``NN``); each publisher is a Zenoh publisher on the topic's key
plus an ``MP`` token, and puts CDR with the attachment rmw_zenoh subscribers require; a
transient-local publisher (``robot_description``) is a zenoh-ext AdvancedPublisher with a
cache, publisher detection and sporadic heartbeats, exactly what rmw_zenoh's transient-local
subscribers (RViz) query; each subscription is a Zenoh subscriber plus an ``MS`` token, and
hands decoded messages to a callback. A subscription reads each sample's attachment as
rmw_zenoh does and, like it, drops a sample without one (or with another layout, such as that
of rmw_zenoh before Jazzy 0.2.4). A sample that does not decode is counted and logged (the
first, then every 100th), never raised into Zenoh's callback thread.

Node and entity ids come from one process-wide counter, so several nodes may share a session.
A node of ``distro="humble"`` writes Humble's keys and tokens (no type hash).
The caller owns the session; :meth:`Node.close` undeclares everything the node declared.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import zenoh
from zenoh import ext

from kinesphere import rmw_zenoh as rz
from kinesphere.errors import KinesphereError
from kinesphere.zconfig import undeclare

log = logging.getLogger(__name__)

HEARTBEAT_S = 0.5
"""Sporadic heartbeat of reliable transient-local publishers (rmw_zenoh's 500 ms), so a
subscriber that missed the last sample recovers it from the cache."""
LOG_EVERY = 100
"""A subscription logs its first bad sample, then every this many."""

_ids = itertools.count(1)


class Node:
    """One ROS node on ``session``: ``name`` in ``namespace`` (``/`` is the root), ``domain``."""

    def __init__(self, session: zenoh.Session, name: str, namespace: str = "/",
                 domain: int = 0, distro: str = "jazzy") -> None:
        rz.typestore()  # fail early, naming the extra, when rosbags is missing
        self.session = session
        self.name = rz.check_node_name(name)
        self.namespace = rz.check_namespace(namespace)
        self.domain = rz.check_domain(domain)
        self.distro = rz.check_distro(distro)
        self.zid = str(session.info.zid())
        self.node_id = next(_ids)
        self._entities: list[Publisher | Subscription] = []
        self._lock = threading.Lock()
        self._token: zenoh.LivelinessToken | None = session.liveliness().declare_token(
            rz.node_token(self.domain, self.zid, self.node_id, self.namespace, self.name)
        )

    def resolve(self, topic: str) -> str:
        """The absolute topic of a name relative to this node's namespace."""
        return rz.resolve(self.namespace, topic)

    def token(self, kind: rz.EntityKind, topic: str, ros_type: str, qos: rz.Qos) -> str:
        """A fresh endpoint token of this node (each call takes a new entity id)."""
        return rz.endpoint_token(kind, self.domain, self.zid, self.node_id, next(_ids),
                                 self.namespace, self.name, topic, ros_type, qos,
                                 distro=self.distro)

    def publisher(self, topic: str, ros_type: str, qos: rz.Qos | None = None) -> Publisher:
        """A publisher on ``topic`` (relative names resolve against the namespace)."""
        pub = Publisher(self, self.resolve(topic), ros_type, qos or rz.Qos())
        with self._lock:
            self._entities.append(pub)
        return pub

    def subscription(self, topic: str, ros_type: str, on_message: Callable[[Any], None],
                     qos: rz.Qos | None = None, *, max_bytes: int = rz.MAX_PAYLOAD,
                     any_hash: bool = True) -> Subscription:
        """Call ``on_message(msg)`` (on a Zenoh thread) for each decodable sample; a
        KinesphereError it raises counts the sample as rejected, like one that did not decode."""
        sub = Subscription(self, self.resolve(topic), ros_type, on_message, qos or rz.Qos(),
                           max_bytes, any_hash)
        with self._lock:
            self._entities.append(sub)
        return sub

    def forget(self, entity: Publisher | Subscription) -> None:
        with self._lock:
            if entity in self._entities:
                self._entities.remove(entity)

    def close(self) -> None:
        """Undeclare every entity of the node, then the node's own token."""
        with self._lock:
            entities, self._entities = self._entities, []
            token, self._token = self._token, None
        for e in entities:
            e.close()
        undeclare(token)  # None when already closed


class Publisher:
    """Puts messages of one type on one topic, each with a fresh sequence number."""

    def __init__(self, node: Node, topic: str, ros_type: str, qos: rz.Qos) -> None:
        self.node = node
        self.topic = topic
        self.ros_type = ros_type
        self.key = rz.topic_key(node.domain, topic, ros_type, distro=node.distro)
        token = node.token(rz.EntityKind.PUBLISHER, topic, ros_type, qos)
        self.gid = rz.gid_of(token)
        self._seq = itertools.count(1)
        reliability = zenoh.Reliability.RELIABLE if qos.reliable else zenoh.Reliability.BEST_EFFORT
        self._pub: zenoh.Publisher | ext.AdvancedPublisher
        if qos.transient_local:
            self._pub = ext.declare_advanced_publisher(
                node.session, self.key, reliability=reliability,
                congestion_control=zenoh.CongestionControl.DROP,
                cache=ext.CacheConfig(max(1, qos.depth)), publisher_detection=True,
                sample_miss_detection=ext.MissDetectionConfig(
                    heartbeat=None, sporadic_heartbeat=HEARTBEAT_S
                ) if qos.reliable else None,
            )
        else:
            self._pub = node.session.declare_publisher(
                self.key, reliability=reliability,
                congestion_control=zenoh.CongestionControl.DROP,
            )
        self._token = node.session.liveliness().declare_token(token)

    def put(self, message: object) -> None:
        """Serialise ``message`` (a rosbags object of this type) and put it."""
        self.put_cdr(rz.serialize(message, self.ros_type))

    def put_cdr(self, payload: bytes) -> None:
        attachment = rz.Attachment(next(self._seq), time.time_ns(), self.gid)
        self._pub.put(payload, attachment=attachment.encode())

    def matched(self, timeout: float = 5.0) -> bool:
        """Wait until a subscriber matches (plain publishers only; True for cached ones)."""
        from kinesphere.zconfig import wait_matching

        if isinstance(self._pub, zenoh.Publisher):
            return wait_matching(self._pub, timeout)
        return True

    def close(self) -> None:
        undeclare(self._token, self._pub)
        self.node.forget(self)


class Subscription:
    """Decodes the samples of one topic and hands each message to a callback."""

    def __init__(self, node: Node, topic: str, ros_type: str, on_message: Callable[[Any], None],
                 qos: rz.Qos, max_bytes: int, any_hash: bool) -> None:
        self.node = node
        self.topic = topic
        self.ros_type = ros_type
        self.on_message = on_message
        self.max_bytes = max_bytes
        self.received = 0
        self.rejected = 0
        self.last_error = ""
        self.last_attachment: rz.Attachment | None = None
        """The attachment of the latest sample read (publisher gid, sequence, source time)."""
        self.key = rz.topic_key(node.domain, topic, ros_type, any_hash=any_hash)
        if qos.transient_local:
            self._sub: Any = ext.declare_advanced_subscriber(
                node.session, self.key, self._on,
                history=ext.HistoryConfig(detect_late_publishers=True,
                                          max_samples=max(1, qos.depth)),
                subscriber_detection=True,
            )
        else:
            self._sub = node.session.declare_subscriber(self.key, self._on)
        self._token = node.session.liveliness().declare_token(
            node.token(rz.EntityKind.SUBSCRIPTION, topic, ros_type, qos)
        )

    def _on(self, sample: zenoh.Sample) -> None:
        try:
            self.last_attachment = rz.Attachment.decode(sample.attachment)
            size = len(sample.payload)
            if size > self.max_bytes:  # before copying it out of Zenoh's buffer
                raise KinesphereError("malformed", f"{size} bytes exceed {self.max_bytes}")
            msg = rz.deserialize(sample.payload.to_bytes(), self.ros_type, self.max_bytes)
        except KinesphereError as exc:
            self._reject(exc)
            return
        try:
            self.on_message(msg)
        except KinesphereError as exc:  # the handler found the content wrong
            self._reject(exc)
            return
        except Exception:  # a callback bug must not kill Zenoh's thread or go unseen
            log.exception("%s: message handler failed", self.topic)
        self.received += 1

    def _reject(self, exc: KinesphereError) -> None:
        self.rejected += 1
        self.last_error = exc.message
        if self.rejected % LOG_EVERY == 1:
            log.warning("%s: dropped sample %d: %s", self.topic, self.rejected, exc.message)

    def close(self) -> None:
        undeclare(self._token, self._sub)
        self.node.forget(self)
