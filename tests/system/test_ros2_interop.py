"""ROS 2 software written by others receives kinesphere, and drives it.

The ROS side is zenoh-ros2-sdk (PyPI, Apache-2.0), an rmw_zenoh client in Python with its own
keys, graph tokens, type hashes, QoS text and attachment (``sdk_peer.py`` drives it), run as a
process joined to kinesphere's router: once with the eclipse-zenoh of the test venv, once from
a venv of its own with the eclipse-zenoh Jazzy's rmw_zenoh 0.2.9 links (1.6.2). Attachments
are also read with that venv's zenoh-ext serialiser, the robots' frames checked against
yourdfpy's forward kinematics of the URDF the peer received. Where the SDK cannot (its
transient-local query does not find publishers of namespaced topics such as
``/baxter_1/robot_description``: it leaves their ``/`` unmangled), the peer subscribes as
rmw_zenoh does, with zenoh-ext's AdvancedSubscriber, and decodes with the SDK's type store.
"""

from __future__ import annotations

import io
import math
import os
import subprocess
import sys
import threading
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from contextlib import ExitStack
from dataclasses import dataclass
from functools import partial
from importlib.metadata import version
from typing import Any

import numpy as np
import pytest
import xxhash
import yourdfpy
import zenoh
from rosbags.typesys.stores.ros2_jazzy import tf2_msgs__msg__TFMessage as TFMessage

from kinesphere import zconfig
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import RobotState, SpatialCommand
from kinesphere.robots.agent.options import Ros2BodyOptions
from support.agents import CommandSender, DatabankProcess, StateWatch, joints_close, running_agent
from support.paths import ROOT
from support.ros2 import GraphWatch, RosTap
from support.ros2_peer import JAZZY_ZENOH, SdkPeer
from support.urdf_fk import set_cfg
from support.wait import WAIT_S, stop_process

JS = "sensor_msgs/msg/JointState"
STRING = "std_msgs/msg/String"
TF = TFMessage.__msgtype__
ODOM = "nav_msgs/msg/Odometry"
JOY = "sensor_msgs/msg/Joy"
ROBOTS = {"baxter-1": "baxter", "packbot": "packbot"}
"""A fixed arm robot and a tracked base with flippers."""
NODE = "/NN/%/%/kinesphere_bridge"
"""The end of the bridge node's liveliness token (rmw_zenoh's graph)."""
JS_TOKEN = "/MP/%/%/kinesphere_bridge/%baxter_1%joint_states/"
"""Part of the token of the bridge's publisher of baxter-1's joint states."""

pytestmark = pytest.mark.processes


class Proc:
    """A kinesphere command in a subprocess, its stderr lines kept (and waited on)."""

    def __init__(self, *args: str) -> None:
        self.lines: list[str] = []
        self._cond = threading.Condition()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "kinesphere.cli", *args], cwd=ROOT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"}, stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE, text=True)
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            with self._cond:
                self.lines.append(line)
                self._cond.notify_all()

    def wait_line(self, text: str) -> str:
        with self._cond:
            if not self._cond.wait_for(lambda: any(text in ln for ln in self.lines), WAIT_S):
                raise AssertionError(f"no {text!r} from {self.proc.args!r}: {self.lines[-20:]}")
            return next(ln for ln in self.lines if text in ln)

    def stop(self) -> int:
        return stop_process(self.proc)


@dataclass
class Site:
    """kinesphere's router, the real databank, agents and ``kinesphere ros2 bridge``."""

    endpoint: str
    watcher: zenoh.Session
    databank: DatabankProcess
    watches: dict[str, StateWatch]
    bridge_zid: str
    graph: list[str]

    def state(self, robot_id: str, stamp_ns: int) -> RobotState:
        """The robot's own RobotState with this stamp (it may reach the test's watch a
        moment after the bridge republished it)."""
        watch = self.watches[robot_id]
        match = [s for s in list(watch.states) if s.stamp_ns == stamp_ns]
        if match:
            return match[0]
        return watch.wait(lambda s: s.stamp_ns == stamp_ns,
                          f"the state of {robot_id} stamped {stamp_ns}")


@pytest.fixture(scope="module")
def site() -> Iterator[Site]:
    with ExitStack() as stack:
        router_ep = zconfig.loopback_endpoint()
        router = Proc("router", "--listen", router_ep)
        stack.callback(router.stop)
        router.wait_line("up, listening on")
        watcher = stack.enter_context(zconfig.session(
            config=zconfig.loopback_config(router_ep)))
        bank = DatabankProcess(router_ep, watcher)
        bank.start()
        stack.callback(bank.stop)
        watches = {}
        for rid, platform in ROBOTS.items():
            _, watches[rid] = stack.enter_context(
                running_agent(router_ep, platform, rid, speed=1.0))
        bridge = Proc("ros2", "bridge", "--connect", router_ep)
        stack.callback(bridge.stop)
        bridge.wait_line("bridging kinesphere robots")
        # the packbot drives a little (its odometry and base frame move), then holds
        with zconfig.session(config=zconfig.loopback_config(router_ep)) as s:
            op = CommandSender(s, "packbot")
            seq = op.send(drive=("left-forward", 0.8), ttl_ms=1500)
            watches["packbot"].after(seq, lambda st: abs(st.base_pose[2]) > 0.2,
                                     "the packbot turning")
            op.close()
        # every latched topic out before any ROS peer joins: the peers are late joiners
        graph = GraphWatch(watcher, 0)

        def described(ts: set[str]) -> bool:
            # every token the tests read from this snapshot: a liveliness subscriber's tokens
            # trickle in, in no set order (the node's own may come after its topics')
            return any(t.endswith(NODE) for t in ts) and any(JS_TOKEN in t for t in ts) and all(
                any(f"%{r}%robot_description/" in t for t in ts) for r in ("baxter_1", "packbot"))

        tokens = sorted(graph.wait(described, "the bridge's node describing both robots"))
        graph.close()
        node = next(t for t in tokens if t.endswith(NODE))
        static = RosTap(watcher, 0, "/tf_static", TFMessage, history=True)
        static.wait(lambda m: {t.child_frame_id.split("/")[0] for t in m.transforms}
                    == {"baxter_1", "packbot"}, "/tf_static of both robots")
        static.close()
        yield Site(router_ep, watcher, bank, watches, node.split("/")[2], tokens)


def _matrix(t: dict[str, Any]) -> np.ndarray:
    """The 4x4 matrix of a geometry_msgs/Transform (as the peer's JSON)."""
    q = t["rotation"]
    x, y, z, w = q["x"], q["y"], q["z"], q["w"]
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    p = t["translation"]
    m[:3, 3] = [p["x"], p["y"], p["z"]]
    return m


def _tf_of(ros_id: str, msg: dict[str, Any]) -> bool:
    """A /tf message (the peer's JSON) about robot ``ros_id``'s frames."""
    return str(msg["transforms"][0]["child_frame_id"]).startswith(f"{ros_id}/")


def _robot_up(name: str, event: dict[str, Any]) -> bool:
    """The peer's event that its stand-in robot ``name`` runs."""
    return bool(event["event"] == "robot" and event["name"] == name)


def _stamp(header: dict[str, Any]) -> int:
    return int(header["stamp"]["sec"]) * 1_000_000_000 + int(header["stamp"]["nanosec"])


def _check_frames(site: Site, rid: str, tf: dict[str, Any], static: list[dict[str, Any]],
                  urdf_text: str) -> int:
    """Every link's pose in ``odom``, chained from the /tf and /tf_static the peer received,
    equals yourdfpy's forward kinematics of the received URDF at the robot's own state (and
    its base pose). Returns the number of links checked."""
    ros_id = rid.replace("-", "_")
    edges: dict[str, tuple[str, np.ndarray]] = {}
    for t in tf["transforms"] + [t for m in static for t in m["transforms"]]:
        if t["child_frame_id"].startswith(f"{ros_id}/"):
            edges[t["child_frame_id"]] = (t["header"]["frame_id"], _matrix(t["transform"]))
    state = site.state(rid, _stamp(tf["transforms"][0]["header"]))
    urdf = yourdfpy.URDF.load(io.StringIO(urdf_text), build_scene_graph=True,
                              load_meshes=False, build_collision_scene_graph=False)
    set_cfg(urdf, dict(zip(state.joint_names, state.q, strict=True)))
    root = urdf.base_link
    x, y, yaw = state.base_pose
    base = np.eye(4)
    base[:3, :3] = [[math.cos(yaw), -math.sin(yaw), 0.0], [math.sin(yaw), math.cos(yaw), 0.0],
                    [0.0, 0.0, 1.0]]
    base[:3, 3] = [x, y, 0.0]
    for link in urdf.link_map:
        frame, chained = f"{ros_id}/{link}", np.eye(4)
        while frame != "odom":
            assert frame in edges, f"no transform to {frame} (from {link}) on /tf or /tf_static"
            parent, m = edges[frame]
            chained = m @ chained
            frame = parent
        expected = base @ urdf.get_transform(link, root)
        assert np.allclose(chained, expected, atol=1e-9), (link, chained, expected)
    return len(urdf.link_map)


LATCHED_TRIES = 3
"""Late joins of the SDK's transient-local subscription before the test gives up on one."""


def _latched_sub(site: Site, peer: SdkPeer, name: str, topic: str, ros_type: str
                 ) -> dict[str, Any]:
    """The SDK's transient-local subscription, made once the bridge's publisher is in the
    peer's graph; its ``subscribed`` event, whose ``name`` is the subscription that got the
    latched message. The SDK's history query is one liveliness query and one query, each with
    its own 2 s deadline, made as it subscribes and never again: while the late joiner's link
    to the bridge is still opening (peers link up by gossip after they join, and the router
    answers neither for a peer), or when a loaded host answers after the deadline, it finds
    nothing and the latched message is missed for good. rmw_zenoh's AdvancedSubscriber asks
    each publisher when its token appears, with no deadline; a ROS node sees the publisher in
    its graph first. The SDK answers its query before it says ``subscribed``, so a
    subscription that heard nothing by then missed it: another late joiner (a new
    subscription, its own node) asks again, up to LATCHED_TRIES times; each one that gets the
    message got it from the bridge's cache, the only place it is."""
    mangled = "%" + topic.strip("/").replace("/", "%")
    peer.in_graph(f"@ros2_lv/{peer.domain}/{site.bridge_zid}/**",
                  lambda t: "/MP/" in t and f"/{mangled}/" in t,
                  f"the bridge's {topic} publisher in the peer's graph")
    for attempt in range(1, LATCHED_TRIES + 1):
        joiner = name if attempt == 1 else f"{name}_{attempt}"
        subscribed = peer.sub(joiner, topic, ros_type, transient_local=True)
        if peer.messages(joiner):
            break
    return subscribed


@pytest.mark.parametrize("zenoh_version", [None, JAZZY_ZENOH],
                         ids=["zenoh-of-the-tests", f"jazzy-zenoh-{JAZZY_ZENOH}"])
def test_ros2_peer_receives_every_robot_from_the_bridge(site: Site,
                                                        zenoh_version: str | None) -> None:
    peer = SdkPeer(site.endpoint, zenoh_version)
    try:
        assert peer.ready["zenoh"] == (zenoh_version or version("eclipse-zenoh"))
        subs = {
            "js": peer.sub("js", "/baxter_1/joint_states", JS),
            "tf": peer.sub("tf", "/tf", TF),
            "odom": peer.sub("odom", "/packbot/odom", ODOM),
            # late joiners of latched topics: the SDK's own history query where it works ...
            "static": _latched_sub(site, peer, "static", "/tf_static", TF),
            # ... and rmw_zenoh's AdvancedSubscriber where it does not (namespaced topics)
            **{f"desc_{r}": peer.sub(f"desc_{r}", f"/{r}/robot_description", STRING,
                                     transient_local=True, history=True)
               for r in ("baxter_1", "packbot")},
        }
        # keys: the SDK's own, from its own type hashes; the bridge's match them
        assert subs["js"]["key"] == ("0/baxter_1/joint_states/sensor_msgs::msg::dds_::"
                                     "JointState_/RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd"
                                     "33a0350f11c5882bc9179260e")

        # joint states: the robot's own, bit for bit; the attachment read by the SDK and by
        # this zenoh's zenoh-ext alike; the sample timestamped by the bridge's session
        js = peer.message("js")
        state = site.state("baxter-1", _stamp(js["header"]))
        assert js["name"] == state.joint_names and js["position"] == state.q
        sample = peer.sample("js")
        assert sample["attachment_len"] == 33
        assert sample["zenoh_ext"] == [sample["seq"], sample["source_ns"], sample["gid"]]
        token = next(t for t in site.graph if JS_TOKEN in t)
        digest = xxhash.xxh3_128(token.encode()).digest()  # rmw_zenoh: low 64 bits, then high
        assert sample["gid"] == (digest[8:][::-1] + digest[:8][::-1]).hex()
        assert sample["timestamp_id"] == site.bridge_zid, "timestamped by the bridge's session"

        # the URDFs, to a late joiner; the frames robot_state_publisher would send, against
        # yourdfpy's forward kinematics of that URDF
        urdfs = {}
        for r, platform in (("baxter_1", "baxter"), ("packbot", "packbot")):
            urdfs[r] = peer.message(f"desc_{r}")["data"]
            root = ET.fromstring(urdfs[r])
            assert root.get("name") == platform and root.findall("body_part") == []
        # one latched /tf_static for the whole fleet, as tf2's static broadcaster keeps it
        static = [peer.message(subs["static"]["name"])]
        assert {t["child_frame_id"].split("/")[0] for t in static[0]["transforms"]} == {
            "baxter_1", "packbot"}
        for rid in ROBOTS:
            r = rid.replace("-", "_")
            tf = peer.message("tf", partial(_tf_of, r), f"/tf of {r}")
            assert _check_frames(site, rid, tf, static, urdfs[r]) > 5

        # odometry of the base that turned: the robot's own base pose
        odom = peer.message("odom", lambda m: abs(m["pose"]["pose"]["orientation"]["z"]) > 0.05,
                            "the packbot's odometry, turned")
        x, y, yaw = site.state("packbot", _stamp(odom["header"])).base_pose
        p, q = odom["pose"]["pose"]["position"], odom["pose"]["pose"]["orientation"]
        assert (p["x"], p["y"]) == (x, y) and math.isclose(2 * math.atan2(q["z"], q["w"]), yaw)
        packbot = ET.fromstring(urdfs["packbot"])
        children = {c.get("link") for c in packbot.iter("child")}
        root_link = next(str(ln.get("name")) for ln in packbot.iter("link")
                         if ln.get("name") not in children)
        assert (odom["header"]["frame_id"], odom["child_frame_id"]) == (
            "odom", f"packbot/{root_link}")
    finally:
        peer.close()


def test_ros2_peer_drives_the_gamepad_and_is_driven_by_the_ros2_body(site: Site) -> None:
    """The SDK's Joy publisher into ``kinesphere gamepad --input ros2:/joy``; the ROS 2 body
    streaming to the SDK's subscribers and reading joint states and odometry from its
    publishers (a robot as simple as can be, ``sdk_peer.py``'s ``robot``)."""
    arm, arm_ns, base, base_ns = "baxter-ros", "/baxter_ros", "packbot-ros", "/packbot_ros"
    peer = SdkPeer(site.endpoint)
    with ExitStack() as stack:
        stack.callback(peer.close)
        for name, ns, platform, mobile in (("arm", arm_ns, "baxter", False),
                                           ("base", base_ns, "packbot", True)):
            p = load_platform(platform)
            peer.send(op="robot", name=name, namespace=ns, every=0.02, base=mobile,
                      joints=dict(zip(p.joint_names, p.neutral_vector().tolist(), strict=True)))
            peer.wait(partial(_robot_up, name), f"robot {name}")
        _, watch = stack.enter_context(running_agent(
            site.endpoint, "baxter", arm, speed=1.0, control_rate=200.0, body="ros2",
            ros2=Ros2BodyOptions(namespace=arm_ns)))
        _, base_watch = stack.enter_context(running_agent(
            site.endpoint, "packbot", base, speed=1.0, control_rate=200.0, body="ros2",
            ros2=Ros2BodyOptions(namespace=base_ns)))

        # a ROS joystick: the SDK's sensor_msgs/Joy at joy's 20 Hz autorepeat
        gamepad = Proc("gamepad", "--headless", "--input", "ros2:/joy", "--target", arm,
                       "--connect", site.endpoint, "--listen", zconfig.LOOPBACK_ANY_PORT)
        stack.callback(gamepad.stop)
        gamepad.wait_line("input: sensor_msgs/Joy on /joy")
        lb = 9  # game_controller_node's LEFTSHOULDER: the deadman of the default mapping

        def joy(axes: list[float], deadman: bool) -> None:
            buttons = [0] * 15
            buttons[lb] = int(deadman)
            peer.pub("joy", "/joy", JOY, {"header": {"frame_id": "joy"}, "axes": axes,
                                            "buttons": buttons}, every=0.05)

        joy([0.0] * 6, False)
        gamepad.wait_line("ROS 2 Joy on /joy: receiving")
        joy([0.0, 0.0, 1.0, 0.0, 0.0, 0.0], True)  # ROS: right stick full left, deadman held
        goal = site.databank.query("baxter", SpatialCommand("limb_11", "distal_11",
                                                            "left-middle", 3.0)).joints
        reached = watch.wait(lambda st: joints_close(st, goal, 0.02),
                             "the ROS robot at the ECL pose the Joy asked for")
        joy([0.0] * 6, False)
        watch.wait(lambda st: st.status in ("holding", "stopped"), "holding after the release")
        limits = load_platform("baxter").eurdf.limits
        streamed = peer.messages("arm_traj")
        assert streamed and reached.q, "the SDK's subscriber heard the trajectory stream"
        for msg in streamed:
            for n, v in zip(msg["joint_names"], msg["points"][-1]["positions"], strict=True):
                assert limits[n].lower <= v <= limits[n].upper, f"{n}={v} outside its limits"

        # a mobile base: cmd_vel out (within the platform's limits), odometry back in
        spec = load_platform("packbot").base
        with zconfig.session(config=zconfig.loopback_config(site.endpoint)) as s:
            op = CommandSender(s, base)
            seq = op.send(drive=("forward", 1.0), ttl_ms=1000)
            moved = base_watch.after(seq, lambda st: st.base_pose[0] > 0.1,
                                     "the base moved forward by its odometry")
            op.close()
        twists = [m for m in peer.messages("base_cmd_vel") if m["linear"]["x"] > 0]
        assert twists, "the SDK's subscriber heard the base's cmd_vel"
        for t in peer.messages("base_cmd_vel"):
            assert abs(t["linear"]["x"]) <= spec.max_speed + 1e-9 and t["linear"]["y"] == 0.0
            assert abs(t["angular"]["z"]) <= spec.max_yaw_rate + 1e-9
        assert abs(moved.base_pose[1]) < 0.05, "a skid base driven forward stays on its line"
        assert gamepad.stop() == 0


def test_humble_peer_receives_the_bridge_with_ros_distro_humble(site: Site) -> None:
    """Humble's rmw_zenoh writes ``TypeHashNotSupported`` where Jazzy writes the hash: the SDK
    told so subscribes to Humble's keys, and ``--ros-distro humble`` publishes there."""
    bridge = Proc("ros2", "bridge", "--connect", site.endpoint, "--domain", "3",
                  "--ros-distro", "humble")
    peer = SdkPeer(site.endpoint, domain=3, distro="humble")
    try:
        bridge.wait_line("bridging kinesphere robots")
        sub = peer.sub("js", "/baxter_1/joint_states", JS)
        assert sub["key"] == ("3/baxter_1/joint_states/sensor_msgs::msg::dds_::JointState_/"
                              "TypeHashNotSupported")
        js = peer.message("js")
        state = site.state("baxter-1", _stamp(js["header"]))
        assert js["name"] == state.joint_names and js["position"] == state.q
        # the watcher's graph, kept by a liveliness subscriber: a liveliness query made while
        # the watcher's link to this new bridge is still opening finds none of its tokens
        graph = GraphWatch(site.watcher, 3)
        try:
            tokens = graph.wait(lambda ts: any("/kinesphere_bridge/%baxter_1%joint_states/" in t
                                               for t in ts), "the Humble bridge's joint states")
        finally:
            graph.close()
        mine = [t for t in tokens if "/kinesphere_bridge/" in t]
        assert mine and all(t.split("/")[11] == "TypeHashNotSupported" for t in mine), mine
    finally:
        peer.close()
        assert bridge.stop() == 0


def test_humble_messages_are_laid_out_as_jazzy_ones() -> None:
    """Why one CDR serves both distributions: rosbags' Humble definitions of every message
    kinesphere sends or reads are the Jazzy ones, field for field."""
    from rosbags.interfaces import Nodetype
    from rosbags.typesys import Stores, get_typestore

    from kinesphere import ros2msgs as rm

    humble, jazzy = get_typestore(Stores.ROS2_HUMBLE), get_typestore(Stores.ROS2_JAZZY)
    types = (rm.JOINT_STATE, rm.JOY, rm.TF_MESSAGE, rm.STRING, rm.JOINT_TRAJECTORY,
             rm.FLOAT64_MULTI_ARRAY, rm.TWIST, rm.TWIST_STAMPED, rm.ODOMETRY)
    seen: set[str] = set()
    todo = list(types)
    while todo:
        t = todo.pop()
        if t in seen:
            continue
        seen.add(t)
        assert humble.fielddefs[t] == jazzy.fielddefs[t], t
        for _, (node, details) in jazzy.fielddefs[t][1]:
            if node == Nodetype.NAME:
                todo.append(str(details))
            elif node in (Nodetype.ARRAY, Nodetype.SEQUENCE) and details[0][0] == Nodetype.NAME:
                todo.append(str(details[0][1]))
    assert len(seen) > len(types)


RIHS01 = {
    # as `ros2 topic info -v` prints them on Jazzy (joint_state_broadcaster, amcl, a
    # joint_trajectory_controller) and as other rmw_zenoh clients pin them in public code
    JS: "a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    TF: "e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "trajectory_msgs/msg/JointTrajectory":
        "179b33eba59d676f6d967ac71fe35e7ca2f64b2f3928f4a018cec115e213796e",
    JOY: "0d356c79cad3401e35ffeb75a96a96e08be3ef896b8b83841d73e890989372c5",
    "std_msgs/msg/Float64MultiArray":
        "1025ddc6b9552d191f89ef1a8d2f60f3d373e28b283d8891ddcc974e8c55397f",
    "geometry_msgs/msg/Twist": "9c45bf16fe0983d80e3cfe750d6835843d265a9a6c46bd2e609fcddde6fb8d2a",
    "geometry_msgs/msg/TwistStamped":
        "5f0fcd4f81d5d06ad9b4c4c63e3ea51b82d6ae4d0558f1d475229b1121db6f64",
    ODOM: "3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    STRING: "df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
}


def test_type_hashes_are_the_ones_ros_prints() -> None:
    from kinesphere import rmw_zenoh as rz

    for ros_type, digest in RIHS01.items():
        assert rz.type_hash(ros_type) == f"RIHS01_{digest}", ros_type
        assert rz.type_hash(ros_type, "humble") == "TypeHashNotSupported"
