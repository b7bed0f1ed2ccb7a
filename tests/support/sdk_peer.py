"""A ROS 2 peer made of zenoh-ros2-sdk (an rmw_zenoh client written by others), driven over
stdin/stdout by the interop tests (``tests/system/test_ros2_interop.py``, through
``support.ros2_peer``).

It imports nothing of kinesphere: it runs in the test venv, or in a venv of its own holding
the eclipse-zenoh that Jazzy's rmw_zenoh links (the version-skew test). Keys, graph tokens, type
hashes, QoS text and the attachment it writes are the SDK's; its CDR is rosbags' (the SDK's
type store, built from message definitions); the attachments it receives are read with the
SDK's ``Attachment`` and with this venv's zenoh-ext serialiser. No network: the SDK's message
definitions, which it would clone from GitHub, are written from rosbags' type store into a
temporary directory first.

Protocol, one JSON object per line. Out: ``{"event": "ready", ...}`` once, then ``msg``
(a message received, as JSON), ``sample`` (what the raw sample looked like: attachment read
both ways, Zenoh timestamp), ``sent`` and ``error`` events. In, ``op``:

- ``sub``: ``name``, ``topic``, ``type``, ``transient_local`` (bool; the SDK's own history
  query), ``history`` (bool: zenoh-ext's AdvancedSubscriber as rmw_zenoh subscribes, decoded
  with the SDK's type store, for topics the SDK's query cannot reach);
- ``pub``: ``name``, ``topic``, ``type``, ``fields`` (JSON of the message); ``every`` (s,
  optional) repeats it at that period until the next ``pub`` of that name or ``stop``;
- ``robot``: ``name``, ``namespace``, ``joints`` (name -> position), ``every`` (s), ``base``
  (bool): a ros2_control robot as simple as can be, made of the SDK's publishers and
  subscribers: it publishes ``joint_states`` every period, jumps to the last point of each
  ``joint_trajectory_controller/joint_trajectory`` it hears, and with ``base`` integrates the
  ``cmd_vel`` Twist it hears into the pose it publishes on ``odom``; what it hears is emitted
  as ``msg`` events of ``<name>_traj`` and ``<name>_cmd_vel``;
- ``graph``: ``pattern``: watch the ROS graph as rmw_zenoh's graph cache does, a liveliness
  subscriber with history on ``pattern``; each token that appears is a ``token`` event (its
  ``key``);
- ``stop``: ``name``; ``quit``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import threading
import time
from importlib.metadata import version
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from rosbags.typesys import Stores, get_typestore

_out = threading.Lock()


def emit(**event: Any) -> None:
    with _out:
        sys.stdout.write(json.dumps(event) + "\n")
        sys.stdout.flush()


def write_definitions(store: Any, root: Path) -> None:
    """Every message type of ``store`` as ``<root>/<pkg>/msg/<Name>.msg`` (what the SDK reads
    before it would clone a repository), from rosbags' own definitions."""
    for typename in store.fielddefs:
        pkg, kind, name = typename.split("/")
        if kind != "msg":
            continue
        text, _ = store.generate_msgdef(typename, ros_version=2)
        own = text.split("\n" + "=" * 80 + "\n", 1)[0]  # the type's part, before its deps
        path = root / pkg / "msg" / f"{name}.msg"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(own + ("\n" if own else ""))


def to_json(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [to_json(v) for v in value]
    if hasattr(value, "__dataclass_fields__"):
        return {k: to_json(getattr(value, k)) for k in value.__dataclass_fields__
                if not k.startswith("__")}
    if isinstance(value, (np.integer, np.floating)):
        return value.item()
    return value


def build(store: Any, typename: str, value: dict[str, Any]) -> Any:
    """A message of ``typename`` (from the SDK's store) from its JSON."""
    _, fields = store.fielddefs[typename]
    kwargs = {}
    for name, (node, details) in fields:
        v = value.get(name)
        kwargs[name] = _field(store, node, details, v)
    return store.types[typename](**kwargs)


def _field(store: Any, node: int, details: Any, v: Any) -> Any:
    base, named, array, sequence = 1, 2, 3, 4  # rosbags' Nodetype
    if node == base:
        kind = details[0]
        if v is None:
            return "" if kind == "string" else (False if kind == "bool" else 0)
        return v
    if node == named:
        return build(store, details, v or {})
    sub_node, sub_details = details[0]
    items = v or []
    if node == array and not items:
        items = [None] * details[1]
    if sub_node == base and sub_details[0] != "string":
        dtype = {"float32": np.float32, "float64": np.float64, "int8": np.int8,
                 "uint8": np.uint8, "int16": np.int16, "uint16": np.uint16, "int32": np.int32,
                 "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64,
                 "bool": np.bool_, "byte": np.uint8, "char": np.uint8}[sub_details[0]]
        return np.array([0 if x is None else x for x in items], dtype=dtype)
    assert node in (array, sequence)
    return [_field(store, sub_node, sub_details, x) for x in items]


class Peer:
    def __init__(self, router: str, domain: int, distro: str) -> None:
        host, port = router.removeprefix("tcp/").rsplit(":", 1)
        self.router = (host, int(port))
        self.domain = domain
        self.distro = distro
        from zenoh_ros2_sdk import ZenohSession
        from zenoh_ros2_sdk.message_registry import get_registry

        store = get_typestore(Stores.ROS2_HUMBLE if distro == "humble" else Stores.ROS2_JAZZY)
        self._defs = tempfile.TemporaryDirectory()
        write_definitions(store, Path(self._defs.name))
        get_registry(self._defs.name)  # the SDK's registry reads these first
        self.sdk = ZenohSession.get_instance(*self.router)
        self.subs: dict[str, Any] = {}
        self.pubs: dict[str, Any] = {}
        self.repeats: dict[str, threading.Event] = {}
        self.robots: dict[str, tuple[list[Any], list[Any]]] = {}
        self.graphs: list[Any] = []

    def _kw(self) -> dict[str, Any]:
        kw: dict[str, Any] = {"domain_id": self.domain, "router_ip": self.router[0],
                              "router_port": self.router[1]}
        if self.distro == "humble":
            kw["type_hash"] = "TypeHashNotSupported"  # Humble's rmw_zenoh has no type hashes
        return kw

    def sub(self, name: str, topic: str, type: str, transient_local: bool = False,
            history: bool = False) -> None:
        ros_type = type
        from zenoh_ros2_sdk import ROS2Subscriber
        from zenoh_ros2_sdk.attachment import Attachment
        from zenoh_ros2_sdk.qos import QosDurability, QosProfile

        def on_message(msg: Any) -> None:
            emit(event="msg", name=name, msg=to_json(msg))

        qos = QosProfile(durability=QosDurability.TRANSIENT_LOCAL, history_depth=1) \
            if transient_local else None
        sdk_sub = ROS2Subscriber(topic, ros_type, on_message if not history else lambda m: None,
                                 qos=qos, node_name=f"peer_{name}", **self._kw())
        session = self.sdk.session
        store = self.sdk.store

        def on_sample(sample: zenoh.Sample) -> None:
            """The sample as rmw_zenoh would see it: its attachment read by the SDK and by
            zenoh-ext (which must agree on a 16-byte gid), its Zenoh timestamp."""
            raw = None if sample.attachment is None else sample.attachment.to_bytes()
            info: dict[str, Any] = {"attachment_len": None if raw is None else len(raw)}
            if raw is not None and sample.attachment is not None:
                a = Attachment.from_bytes(raw)
                info.update(seq=a.sequence_id, gid=a.gid.hex(), source_ns=a.timestamp_ns)
                from zenoh.ext import Int64, z_deserialize

                seq, ts, gid = z_deserialize(tuple[Int64, Int64, bytes], sample.attachment)
                info["zenoh_ext"] = [int(seq), int(ts), bytes(gid).hex()]
            stamp = sample.timestamp
            info["timestamp_id"] = None if stamp is None else str(stamp.get_id())
            emit(event="sample", name=name, key=str(sample.key_expr), **info)
            if history:
                msg = store.deserialize_cdr(sample.payload.to_bytes(), ros_type)
                emit(event="msg", name=name, msg=to_json(msg))

        if history:  # as rmw_zenoh subscribes to a transient-local topic
            from zenoh import ext

            raw_sub: Any = ext.declare_advanced_subscriber(
                session, sdk_sub.keyexpr, on_sample,
                history=ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
                subscriber_detection=True)
        else:
            raw_sub = session.declare_subscriber(sdk_sub.keyexpr, on_sample)
        self.subs[name] = (sdk_sub, raw_sub)
        emit(event="subscribed", name=name, key=sdk_sub.keyexpr)

    def pub(self, name: str, topic: str, type: str, fields: dict[str, Any],
            every: float | None = None) -> None:
        ros_type = type
        from zenoh_ros2_sdk import ROS2Publisher

        if name not in self.pubs:
            self.pubs[name] = ROS2Publisher(topic, ros_type, node_name=f"peer_{name}",
                                            **self._kw())
        pub = self.pubs[name]
        msg = build(self.sdk.store, ros_type, fields)
        kwargs = {k: getattr(msg, k) for k in msg.__dataclass_fields__}
        self.stop(name)
        if every is None:
            pub.publish(**kwargs)
            emit(event="sent", name=name, count=pub.sequence_number)
            return
        stop = self.repeats[name] = threading.Event()

        def repeat() -> None:  # a node's timer (joy's autorepeat), not a test's wait
            while True:
                pub.publish(**kwargs)
                emit(event="sent", name=name, count=pub.sequence_number)
                if stop.wait(every):
                    return

        threading.Thread(target=repeat, daemon=True).start()

    def robot(self, name: str, namespace: str, joints: dict[str, float], every: float,
              base: bool = False) -> None:
        from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber

        ns = namespace.rstrip("/")
        q = dict(joints)
        pose = [0.0, 0.0, 0.0]
        twist = [0.0, 0.0, 0.0]
        lock = threading.Lock()

        def on_trajectory(msg: Any) -> None:
            emit(event="msg", name=f"{name}_traj", msg=to_json(msg))
            with lock:
                q.update(zip(msg.joint_names, msg.points[-1].positions.tolist(), strict=True))

        def on_twist(msg: Any) -> None:
            emit(event="msg", name=f"{name}_cmd_vel", msg=to_json(msg))
            with lock:
                twist[:] = [msg.linear.x, msg.linear.y, msg.angular.z]

        kw = self._kw()
        subs = [ROS2Subscriber(f"{ns}/joint_trajectory_controller/joint_trajectory",
                               "trajectory_msgs/msg/JointTrajectory", on_trajectory,
                               node_name=f"{name}_controller", **kw)]
        js = ROS2Publisher(f"{ns}/joint_states", "sensor_msgs/msg/JointState",
                           node_name=f"{name}_broadcaster", **kw)
        odom = None
        if base:
            subs.append(ROS2Subscriber(f"{ns}/cmd_vel", "geometry_msgs/msg/Twist", on_twist,
                                       node_name=f"{name}_base", **kw))
            odom = ROS2Publisher(f"{ns}/odom", "nav_msgs/msg/Odometry",
                                 node_name=f"{name}_odometry", **kw)
        store = self.sdk.store
        stop = self.repeats[name] = threading.Event()

        def stamp() -> dict[str, Any]:
            sec, nanosec = divmod(time.time_ns(), 1_000_000_000)
            return {"stamp": {"sec": sec, "nanosec": nanosec}, "frame_id": ""}

        def cycle() -> None:  # the robot's own control cycle, not a test's wait
            while not stop.wait(every):
                with lock:
                    names, positions = list(q), list(q.values())
                    vx, vy, wz = twist
                    yaw = pose[2] + 0.5 * wz * every  # mid-step heading
                    pose[0] += (math.cos(yaw) * vx - math.sin(yaw) * vy) * every
                    pose[1] += (math.sin(yaw) * vx + math.cos(yaw) * vy) * every
                    pose[2] += wz * every
                    x, y, th = pose
                state = build(store, "sensor_msgs/msg/JointState",
                              {"header": stamp(), "name": names, "position": positions})
                js.publish(**{k: getattr(state, k) for k in state.__dataclass_fields__})
                if odom is not None:
                    o = build(store, "nav_msgs/msg/Odometry", {
                        "header": {**stamp(), "frame_id": "odom"}, "child_frame_id": "base",
                        "pose": {"pose": {"position": {"x": x, "y": y},
                                          "orientation": {"z": math.sin(th / 2),
                                                          "w": math.cos(th / 2)}}}})
                    odom.publish(**{k: getattr(o, k) for k in o.__dataclass_fields__})

        threading.Thread(target=cycle, daemon=True).start()
        self.robots[name] = (subs, [p for p in (js, odom) if p is not None])
        emit(event="robot", name=name)

    def graph(self, pattern: str) -> None:
        def on_token(sample: zenoh.Sample) -> None:
            if sample.kind == zenoh.SampleKind.PUT:
                emit(event="token", key=str(sample.key_expr))

        self.graphs.append(self.sdk.session.liveliness().declare_subscriber(
            pattern, on_token, history=True))

    def stop(self, name: str) -> None:
        event = self.repeats.pop(name, None)
        if event is not None:
            event.set()

    def close(self) -> None:
        for name in list(self.repeats):
            self.stop(name)
        for graph in self.graphs:
            graph.undeclare()
        for sdk_sub, raw_sub in self.subs.values():
            raw_sub.undeclare()
            sdk_sub.close()
        for pub in self.pubs.values():
            pub.close()
        for subs, pubs in self.robots.values():
            for entity in (*subs, *pubs):
                entity.close()
        self.sdk.close()
        self._defs.cleanup()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--router", required=True, help="tcp/HOST:PORT")
    parser.add_argument("--domain", type=int, default=0)
    parser.add_argument("--distro", choices=("jazzy", "humble"), default="jazzy")
    args = parser.parse_args()
    os.environ.setdefault("ZENOH_ROS2_SDK_CACHE", tempfile.mkdtemp(prefix="sdk-cache-"))
    peer = Peer(args.router, args.domain, args.distro)
    emit(event="ready", zenoh=version("eclipse-zenoh"), sdk=version("zenoh-ros2-sdk"),
         zid=peer.sdk.session_id)
    try:
        for line in sys.stdin:
            cmd = json.loads(line)
            op = cmd.pop("op")
            if op == "quit":
                break
            try:
                getattr(peer, op)(**cmd)
            except Exception as exc:  # reported to the test, which fails naming it
                emit(event="error", op=op, error=repr(exc))
    finally:
        peer.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
