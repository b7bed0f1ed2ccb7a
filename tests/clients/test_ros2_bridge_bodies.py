"""The ROS 2 bridge survives any body: a refused one is skipped for its robots and reported
once, and every other platform still gets its robot_description.

Before: one body with XML nested 5,000 deep raised RecursionError in ``plain_urdf`` on the
bridge's one body thread, and no robot got ``robot_description`` or ``/tf`` afterwards.
A queryable on the test hub answers the bodies under the tests' own prefix (the hostile one
first), stand-in robots put states, and the ROS side reads the topics with its own rosbags type
store.
"""

from __future__ import annotations

import threading
import time
from contextlib import ExitStack

import zenoh
from rosbags.typesys.stores.ros2_jazzy import std_msgs__msg__String as String

from kinesphere import zconfig
from kinesphere.clients.options import BridgeOptions
from kinesphere.clients.ros2.bridge import Bridge
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import RobotState, encode
from kinesphere.services.databank.body import body_model
from support.hostile import model, nested
from support.network import OWN_KEYS as KEYS
from support.network import Hub
from support.ros2 import RosTap
from support.wait import WAIT_S

RETRY_S = 0.2


def test_a_refused_body_stops_no_other_platform(hub: Hub) -> None:
    bodies = {"hostile": model(nested(5000), "hostile"),
              "youbot": body_model(load_platform("youbot"))}
    asked: dict[str, int] = {}
    lock = threading.Lock()

    def answer(query: zenoh.Query) -> None:
        with query:
            platform = str(query.key_expr).split("/")[-2]
            with lock:
                asked[platform] = asked.get(platform, 0) + 1
            query.reply(query.key_expr, encode(bodies[platform]))

    with ExitStack() as stack:
        robots = stack.enter_context(zconfig.session(config=zconfig.loopback_config(hub.endpoint)))
        ros = stack.enter_context(zconfig.session(config=zconfig.loopback_config(hub.endpoint)))
        queryable = hub.session.declare_queryable(KEYS.body("*"), answer, complete=True)
        stack.callback(zconfig.undeclare, queryable)
        bridge = Bridge(hub.session, KEYS, BridgeOptions(body_retry_s=RETRY_S))
        stack.callback(bridge.close)
        description = RosTap(ros, 0, "/youbot_1/robot_description", String, history=True)

        def put(rid: str, platform: str, seq: int) -> None:
            robots.put(KEYS.state(rid), encode(RobotState(
                robot_id=rid, platform=platform, seq=seq, stamp_ns=time.time_ns(),
                joint_names=[], q=[], qd=[], base_pose=[0.0, 0.0, 0.0], status="idle",
                last_command_seq=-1)))

        deadline = time.monotonic() + WAIT_S
        seq = 0
        while not asked.get("hostile") and time.monotonic() < deadline:
            put("hostile-1", "hostile", seq)  # first: its body is fetched first
            seq += 1
            time.sleep(0.05)
        while not description.got and time.monotonic() < deadline:
            put("hostile-1", "hostile", seq)
            put("youbot-1", "youbot", seq)
            seq += 1
            time.sleep(0.05)
        urdf = description.wait(what="youbot-1's robot_description").msg.data
        assert 'name="youbot"' in urdf and "body_part" not in urdf
        settle = time.monotonic() + 5 * RETRY_S  # a retried refusal would be asked again
        while time.monotonic() < settle:
            put("hostile-1", "hostile", seq)
            seq += 1
            time.sleep(0.05)
        assert asked["hostile"] == 1, asked
        assert bridge.stats.refused.get("body") == 1, bridge.stats.refused
        assert set(bridge.robots()) == {"hostile-1", "youbot-1"}  # its joint states go on
        description.close()
