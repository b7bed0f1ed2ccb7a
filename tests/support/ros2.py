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
from typing import ClassVar, Generic, Protocol, TypeVar

import zenoh
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.stores.ros2_jazzy import (
    std_msgs__msg__Float64MultiArray as Float64MultiArray,
)
from rosbags.typesys.stores.ros2_jazzy import (
    trajectory_msgs__msg__JointTrajectory as JointTrajectory,
)
from zenoh.ext import Int64, z_deserialize, z_serialize

from kinesphere import zconfig
from support.wait import WAIT_S
from support.watch import Heard

JAZZY = get_typestore(Stores.ROS2_JAZZY)
"""Upper bound for events on a loaded 2-core machine; tests finish far sooner."""


def dds(ros_type: str) -> str:
    pkg, kind, name = ros_type.split("/")
    return f"{pkg}::{kind}::dds_::{name}_"


def key(domain: int, topic: str, ros_type: str) -> str:
    """rmw_zenoh's data key: ``<domain>/<topic without leading slash>/<dds type>/<hash>``."""
    return f"{domain}/{topic.strip('/')}/{dds(ros_type)}/{JAZZY.hash_rihs01(ros_type)}"


def attachment(seq: int, gid: bytes) -> zenoh.ZBytes:
    """rmw_zenoh's attachment (Jazzy >= 0.2.4): the gid is a zenoh-ext sequence (``bytes``)."""
    return z_serialize((Int64(seq), Int64(time.time_ns()), gid))


def read_attachment(sample: zenoh.Sample) -> tuple[int, int, bytes]:
    """(sequence number, source timestamp ns, gid); raises if absent or garbled."""
    assert sample.attachment is not None, "rmw_zenoh subscribers drop samples without one"
    seq, ts, gid = z_deserialize(tuple[Int64, Int64, bytes], sample.attachment)
    assert len(gid) == 16, f"gid of {len(gid)} bytes: not rmw_zenoh's attachment"
    assert len(sample.attachment) == 33, "rmw_zenoh's attachment is 33 bytes"
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


class RosMessage(Protocol):
    """A ROS message class of rosbags' type store (a dataclass naming its ROS type)."""

    __msgtype__: ClassVar[str]


M = TypeVar("M", bound=RosMessage)


@dataclass
class Tapped(Generic[M]):
    """One message a :class:`RosTap` heard, with its attachment and its arrival time."""

    msg: M
    seq: int
    stamp_ns: int
    gid: bytes
    at: float


class RosTap(Heard[Tapped[M]]):
    """Every message on one ROS topic, decoded with rosbags, attachment checked."""

    def __init__(self, session: zenoh.Session, domain: int, topic: str, msg_type: type[M],
                 history: bool = False) -> None:
        super().__init__()
        self.msg_type = msg_type
        self.ros_type = msg_type.__msgtype__
        self.key = key(domain, topic, self.ros_type)
        self.got = self.heard
        self._sub: zconfig.Undeclarable
        if history:  # what rmw_zenoh does for a transient-local subscription
            self._sub = zenoh.ext.declare_advanced_subscriber(
                session, self.key, self._on,
                history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
                subscriber_detection=True,
            )
        else:
            self._sub = session.declare_subscriber(self.key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        seq, ts, gid = read_attachment(sample)
        msg = JAZZY.deserialize_cdr(sample.payload.to_bytes(), self.ros_type)
        assert isinstance(msg, self.msg_type), f"{self.ros_type} decoded as {type(msg)}"
        self.add(Tapped(msg, seq, ts, gid, time.monotonic()))

    def explain(self) -> str:
        return f"on {self.key} ({len(self.got)} other messages)"

    # A tap's predicates read the message itself, not the envelope Heard keeps it in.
    def wait(  # type: ignore[override]
        self, pred: Callable[[M], bool] = lambda m: True, what: str = "a message",
        timeout: float = WAIT_S, *, start: int = 0,
    ) -> Tapped[M]:
        """The first message (from the start) whose ``msg`` satisfies ``pred``."""
        return super().wait(lambda r: pred(r.msg), what, timeout, start=start)

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

    def put(self, msg: object) -> None:
        self.seq += 1
        payload = bytes(JAZZY.serialize_cdr(msg, self.ros_type, little_endian=True))
        self.pub.put(payload, attachment=attachment(self.seq, self.gid))

    def close(self) -> None:
        zconfig.undeclare(self.token, self.pub)


class StandInRobot:
    """A ros2_control robot as the ROS 2 body sees it, in rmw_zenoh's format only.

    Publishes ``<ns>/joint_states`` at ``rate`` Hz (names shuffled, plus a gripper joint the
    eURDF does not have); follows a joint_trajectory_controller on
    ``<ns>/<controller>/joint_trajectory`` (each message replaces the trajectory: linear from
    where the joints are to the last point at its ``time_from_start``, as the controller
    interpolates) or a forward position controller on ``<ns>/<controller>/commands`` (jump to
    the command, in ``order``). Every message received is kept, with its arrival time.
    """

    def __init__(self, session: zenoh.Session, domain: int, ns: str, joints: dict[str, float],
                 interface: str = "trajectory", controller: str = "joint_trajectory_controller",
                 order: list[str] | None = None, rate: float = 100.0) -> None:
        self.names = list(joints)
        self.q = {n: float(v) for n, v in joints.items()}
        self.order = order or self.names
        self.rate = rate
        self.interface = interface
        self.received: list[tuple[float, JointTrajectory | Float64MultiArray]] = []
        self.ticks = 0
        self.moved = (0, time.monotonic())
        """(tick, time) of the last tick in which any joint moved."""
        self._last_q: list[float] = []
        self.publishing = threading.Event()
        self.publishing.set()
        self._plan: tuple[float, dict[str, float], dict[str, float], float] | None = None
        self._cond = threading.Condition()
        self._stop = threading.Event()
        ros_type = ("trajectory_msgs/msg/JointTrajectory" if interface == "trajectory"
                    else "std_msgs/msg/Float64MultiArray")
        suffix = "joint_trajectory" if interface == "trajectory" else "commands"
        self.command_type = ros_type
        self._cmd = session.declare_subscriber(
            key(domain, f"{ns}/{controller}/{suffix}", ros_type), self._on_command)
        zid = str(session.info.zid())
        topic = f"{ns}/{controller}/{suffix}".replace("/", "%")
        self._token = session.liveliness().declare_token(
            f"@ros2_lv/{domain}/{zid}/800/802/MS/%/{ns.replace('/', '%')}/{controller}/{topic}/"
            f"{dds(ros_type)}/{JAZZY.hash_rihs01(ros_type)}/::,10:,:,:,,")
        self.states = RosPublisher(session, domain, f"{ns}/joint_states",
                                   "sensor_msgs/msg/JointState", node="joint_state_broadcaster",
                                   node_id=800, entity_id=801)
        self._thread = threading.Thread(target=self._run, name="stand-in", daemon=True)
        self._thread.start()

    def _on_command(self, sample: zenoh.Sample) -> None:
        read_attachment(sample)  # what rmw_zenoh's subscription would insist on
        msg = JAZZY.deserialize_cdr(sample.payload.to_bytes(), self.command_type)
        now = time.monotonic()
        with self._cond:
            if isinstance(msg, JointTrajectory):
                self.received.append((now, msg))
                point = msg.points[-1]
                t = point.time_from_start.sec + point.time_from_start.nanosec * 1e-9
                goal = dict(zip(msg.joint_names, point.positions.tolist(), strict=True))
                self._plan = (now, dict(self.q), goal, max(t, 1e-3))
            else:
                assert isinstance(msg, Float64MultiArray), f"{self.command_type}: {type(msg)}"
                self.received.append((now, msg))
                self.q.update(zip(self.order, msg.data.tolist(), strict=True))
            self._cond.notify_all()

    def _run(self) -> None:
        js = JAZZY.types["sensor_msgs/msg/JointState"]
        header = JAZZY.types["std_msgs/msg/Header"]
        stamp = JAZZY.types["builtin_interfaces/msg/Time"]
        import numpy as np

        names = [*reversed(self.names), "gripper_finger"]  # order and extras differ from P
        while not self._stop.wait(1.0 / self.rate):  # the robot's own cycle, not a test wait
            with self._cond:
                if self._plan is not None:
                    t0, start, goal, dur = self._plan
                    a = min(1.0, (time.monotonic() - t0) / dur)
                    for n, g in goal.items():
                        self.q[n] = start[n] + a * (g - start[n])
                q = [self.q[n] for n in names[:-1]] + [0.01]
                self.ticks += 1
                if q != self._last_q:
                    self.moved = (self.ticks, time.monotonic())
                self._last_q = q
                self._cond.notify_all()
            if self.publishing.is_set():
                sec, ns = divmod(time.time_ns(), 1_000_000_000)
                self.states.put(js(header=header(stamp=stamp(sec=sec, nanosec=ns), frame_id=""),
                                   name=names, position=np.array(q), velocity=np.array([]),
                                   effort=np.array([])))

    def within(self, pred: Callable[[StandInRobot], bool], timeout: float) -> bool:
        """Whether ``pred(self)`` holds within ``timeout`` s (checked on the robot's cycle)."""
        with self._cond:
            return self._cond.wait_for(lambda: pred(self), timeout)

    def wait(self, pred: Callable[[StandInRobot], bool], what: str,
             timeout: float = WAIT_S) -> None:
        """Wait (on the robot's own cycle) until ``pred(self)`` holds."""
        if not self.within(pred, timeout):
            raise AssertionError(f"stand-in robot never {what}; q = {self.q}")

    def wait_rest(self, ticks: int = 30) -> float:
        """Wait until no joint has moved for ``ticks`` cycles; when it last moved."""
        self.wait(lambda r: r.ticks - r.moved[0] >= ticks, f"rested for {ticks} ticks")
        return self.moved[1]

    def positions(self) -> dict[str, float]:
        with self._cond:
            return dict(self.q)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.states.close()
        zconfig.undeclare(self._token, self._cmd)
