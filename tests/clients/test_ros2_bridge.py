"""``kinesphere ros2 bridge`` seen from the ROS side, with no ROS installed.

Real agents (MuJoCo, Ruckig) and the real databank on a loopback hub; the ROS side subscribes
to rmw_zenoh's keys with plain Zenoh and decodes with its own rosbags type store
(``test_ros2_support``), so key format, CDR, attachment and graph tokens are all checked
against an implementation that is not the one under test.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from contextlib import ExitStack
from functools import partial

import numpy as np
import pytest
from rosbags.typesys.stores.ros2_jazzy import sensor_msgs__msg__JointState as JointState
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__String as String
from rosbags.typesys.stores.ros2_jazzy import tf2_msgs__msg__TFMessage as TFMessage

from kinesphere import zconfig
from kinesphere.clients.options import BridgeOptions
from kinesphere.clients.ros2.bridge import Bridge
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import RobotState, encode
from support.agents import DatabankProcess, StateWatch, running_agent
from support.network import KEYS, Hub
from support.paths import ROOT
from support.ros2 import JAZZY, GraphWatch, RosTap, dds, graph
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

JS, STRING, TF = JointState.__msgtype__, String.__msgtype__, TFMessage.__msgtype__


def _state_with_stamp(watch: StateWatch, stamp_ns: int) -> RobotState:
    """The robot's own RobotState with this stamp (it may reach the test's watch a moment
    after the bridge republished it)."""
    match = [s for s in list(watch.states) if s.stamp_ns == stamp_ns]
    if match:
        return match[0]
    return watch.wait(lambda s: s.stamp_ns == stamp_ns, f"the state stamped {stamp_ns}")


def _stamped_otherwise(before: JointState, msg: JointState) -> bool:
    return bool(msg.header.stamp != before.header.stamp)


def _tf_to(child: str, msg: TFMessage) -> bool:
    return msg.transforms[0].child_frame_id == child


def test_bridge_shows_every_robot_to_ros(hub: Hub, databank: DatabankProcess) -> None:
    _, endpoint = hub
    robots = {"baxter-1": "baxter", "packbot": "packbot"}
    ros_ids = {"baxter-1": "baxter_1", "packbot": "packbot"}
    with ExitStack() as stack:
        ros = stack.enter_context(zconfig.session(config=zconfig.loopback_config(endpoint)))
        watches = {}
        agents = {}
        for rid, platform in robots.items():
            agent, watch = stack.enter_context(running_agent(endpoint, platform, rid, speed=1.0))
            agents[rid], watches[rid] = agent, watch
        taps = {rid: RosTap(ros, 0, f"/{ros_ids[rid]}/joint_states", JointState) for rid in robots}
        tf = RosTap(ros, 0, "/tf", TFMessage)
        bs = stack.enter_context(zconfig.session(config=zconfig.loopback_config(endpoint)))
        bridge = Bridge(bs, KEYS, BridgeOptions())
        stack.callback(bridge.close)

        # joint states: names and positions are the robots' own RobotState, bit for bit
        for rid, tap in taps.items():
            first = tap.wait(what=f"JointState of {rid}")
            later = tap.wait(partial(_stamped_otherwise, first.msg),
                             what=f"a second JointState of {rid}")
            assert later.seq > first.seq >= 1
            assert abs(later.stamp_ns - time.time_ns()) < 60e9 and len(later.gid) == 16
            for r in (first, later):
                m = r.msg
                stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                state = _state_with_stamp(watches[rid], stamp)
                assert list(m.name) == state.joint_names
                assert m.position.tolist() == state.q
                assert m.velocity.tolist() == state.qd
        assert bridge.robots() == ros_ids

        # robot_description: the URDF without labels, latched for late subscribers (RViz)
        for rid, platform in robots.items():
            desc = RosTap(ros, 0, f"/{ros_ids[rid]}/robot_description", String,
                          history=True)
            urdf = ET.fromstring(desc.wait(what=f"URDF of {rid}").msg.data)
            desc.close()
            assert urdf.get("name") == platform and urdf.findall("body_part") == []
            joints = {j.get("name") for j in urdf.findall("joint")}
            assert set(watches[rid].states[-1].joint_names) <= joints

        # tf: odom -> ID/<root link>, at the robot's base pose
        for rid, platform in robots.items():
            child = f"{ros_ids[rid]}/{load_platform(platform).eurdf.root_link}"
            t = tf.wait(partial(_tf_to, child), what=f"tf of {rid}").msg.transforms[0]
            assert t.header.frame_id == "odom"
            stamp = t.header.stamp.sec * 1_000_000_000 + t.header.stamp.nanosec
            x, y, yaw = _state_with_stamp(watches[rid], stamp).base_pose
            q = t.transform.rotation
            assert (t.transform.translation.x, t.transform.translation.y) == (x, y)
            assert np.isclose(2 * np.arctan2(q.z, q.w), yaw) and q.x == q.y == 0.0

        # the graph: one node, and a publisher per topic (what `ros2 topic list -v` shows)
        tokens = graph(ros, 0)
        bridge_zid = str(bs.info.zid())
        assert [t for t in tokens if "/NN/" in t] == [
            t for t in tokens if t.startswith(f"@ros2_lv/0/{bridge_zid}/")
            and t.endswith("/NN/%/%/kinesphere_bridge")
        ]
        assert len([t for t in tokens if "/NN/" in t]) == 1
        js_hash, str_hash = JAZZY.hash_rihs01(JS), JAZZY.hash_rihs01(STRING)
        for ros_id in ros_ids.values():
            assert any(t.endswith(f"/MP/%/%/kinesphere_bridge/%{ros_id}%joint_states/"
                                  f"{dds(JS)}/{js_hash}/::,10:,:,:,,") for t in tokens), tokens
            assert any(t.endswith(f"/MP/%/%/kinesphere_bridge/%{ros_id}%robot_description/"
                                  f"{dds(STRING)}/{str_hash}/:1:,1:,:,:,,") for t in tokens)
        assert any(f"/MP/%/%/kinesphere_bridge/%tf/{dds(TF)}/" in t for t in tokens)

        # a robot that leaves takes its publishers out of the graph
        graph_watch = GraphWatch(ros, 0)
        stack.callback(graph_watch.close)
        graph_watch.wait(lambda ts: any("%packbot%joint_states" in t for t in ts), "packbot")
        agents["packbot"].close()
        graph_watch.wait(lambda ts: not any("%packbot%" in t for t in ts), "packbot gone")
        assert "packbot" not in bridge.robots()
        # its last state arriving after its token went (they travel apart) brings it not back:
        # it did in a loaded full run, and the graph showed packbot for good
        gone = agents["packbot"].last_state
        assert gone is not None
        late = ros.declare_publisher(KEYS.state("packbot"))
        stack.callback(late.undeclare)
        assert zconfig.wait_matching(late, WAIT_S)
        late.put(encode(gone))
        until(lambda: bridge.stats.late >= 1, WAIT_S, "the late state ignored")
        assert "packbot" not in bridge.robots()
        assert not any("%packbot%" in t for t in graph_watch.tokens)
        with running_agent(endpoint, "packbot", "packbot", speed=1.0):  # back: bridged again
            graph_watch.wait(lambda ts: any("%packbot%joint_states" in t for t in ts),
                             "packbot back")
        graph_watch.wait(lambda ts: not any("%packbot%" in t for t in ts), "packbot gone again")
        assert any("%baxter_1%joint_states" in t for t in graph_watch.tokens)
        for tap in taps.values():
            tap.close()
        tf.close()


def _fake_state(robot_id: str, seq: int) -> RobotState:
    return RobotState(robot_id=robot_id, platform="nao", seq=seq, stamp_ns=time.time_ns(),
                      joint_names=["HeadYaw"], q=[0.25], qd=[], base_pose=[0.0, 0.0, 0.0],
                      status="idle", last_command_seq=-1)


def test_bridge_cli_domain_namespace_and_bad_input() -> None:
    """The command as users run it: its own domain and namespace, bad states survived,
    clashing ROS names refused, clean exit on SIGTERM (graph emptied)."""
    with zconfig.loopback_hub() as (hubs, endpoint), ExitStack() as stack:
        ros = stack.enter_context(zconfig.session(config=zconfig.loopback_config(endpoint)))
        tap = RosTap(ros, 7, "/lab/nao_1/joint_states", JointState)
        stack.callback(tap.close)
        proc = subprocess.Popen(
            [sys.executable, "-m", "kinesphere.cli", "ros2", "bridge", "--connect", endpoint,
             "--domain", "7", "--namespace", "lab", "--prefix", KEYS.prefix],
            cwd=ROOT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )
        stack.callback(proc.kill)
        assert proc.stderr is not None
        line = proc.stderr.readline()
        assert "domain 7 as node /lab/kinesphere_bridge" in line, line
        pub = ros.declare_publisher(KEYS.state("nao-1"))
        clash = ros.declare_publisher(KEYS.state("nao_1"))
        assert zconfig.wait_matching(pub, WAIT_S)
        pub.put(b"\xc1 not msgpack")
        pub.put(encode(_fake_state("nao-1", 1)))
        got = tap.wait(what="JointState of nao-1")
        assert list(got.msg.name) == ["HeadYaw"] and got.msg.position.tolist() == [0.25]
        clash.put(encode(_fake_state("nao_1", 1)))  # same ROS name: refused, nao-1 unharmed
        pub.put(encode(_fake_state("nao-1", 2)))
        tap.wait(lambda m: len(tap.got) >= 2, what="a second JointState")
        watch = GraphWatch(ros, 7)
        stack.callback(watch.close)
        tokens = watch.wait(lambda ts: any("%lab%nao_1%joint_states" in t for t in ts)
                            and any(t.endswith("/NN/%/%lab/kinesphere_bridge") for t in ts),
                            "the bridge node and nao_1's publisher")
        assert sum("%lab%nao_1%joint_states" in t for t in tokens) == 1
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=WAIT_S)
        assert proc.returncode == 0, err
        assert "not bridged: its ROS name 'nao_1' is taken" in err
        assert "bad state" in err
        watch.wait(lambda ts: not ts, "an empty graph after the bridge stopped")
        zconfig.undeclare(pub, clash)
