"""ROS 2 over rmw_zenoh: what speaking ROS costs, against baselines measured in the same run.

1. Encoding one JointState (rosbags CDR + the rmw_zenoh attachment) beside encoding the
   RobotState it comes from (msgspec, what every agent already does per state); and the
   frames the bridge adds per state (the joint transforms, /tf's TFMessage and the Odometry,
   CDR) against the same baseline.
2. The bridge's relay latency, RobotState put -> JointState delivered on its ROS key, beside
   a bare relay in the same process that republishes the same bytes unchanged (the floor any
   relay pays: two Zenoh hops and a callback).
"""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
import zenoh

from kinesphere import rmw_zenoh as rz
from kinesphere import ros2msgs as rm
from kinesphere import zconfig
from kinesphere.joint_frames import JointFrames
from kinesphere.keyexpr import Keys
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import RobotState, encode

KEYS = Keys("ros2bench")
ENCODES = 5000
RELAYED = 1500
SPACING_S = 0.002
"""Between two states: faster than a 50 Hz robot, slow enough that nothing queues."""


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


def state(platform: str, seq: int) -> RobotState:
    p = load_platform(platform)
    n = len(p.joint_names)
    return RobotState(robot_id="bench-1", platform=platform, seq=seq, stamp_ns=time.time_ns(),
                      joint_names=list(p.joint_names), q=[0.1 * i for i in range(n)],
                      qd=[0.0] * n, base_pose=[0.0, 0.0, 0.0], status="moving",
                      last_command_seq=seq)


def bench_encode() -> None:
    st = state("baxter", 1)
    gid = rz.gid_of(rz.node_token(0, "ab", 1, "/", "n"))
    ours, base = [], []
    for i in range(ENCODES):
        t0 = time.perf_counter_ns()
        encode(st)
        t1 = time.perf_counter_ns()
        rz.serialize(rm.joint_state(st.joint_names, st.q, st.qd, st.stamp_ns), rm.JOINT_STATE)
        rz.Attachment(i, st.stamp_ns, gid).encode()
        t2 = time.perf_counter_ns()
        base.append((t1 - t0) / 1e3)
        ours.append((t2 - t1) / 1e3)
    mb, mo = pct(base, 50), pct(ours, 50)
    print(f"encode, baxter (14 joints), {ENCODES} messages")
    print(f"  RobotState (msgspec)             p50 {mb:7.1f} us  p99 {pct(base, 99):7.1f} us")
    print(f"  JointState CDR + attachment      p50 {mo:7.1f} us  p99 {pct(ours, 99):7.1f} us"
          f"  ({mo / mb:.0f}x the msgspec encode)")
    frames = JointFrames(load_platform("baxter").eurdf)
    moving = frames.moving
    pairs = [("odom", "b/base")] + [(f"b/{frames.parents[i]}", f"b/{frames.children[i]}")
                                    for i in range(len(frames.names)) if moving[i]]
    template = rm.TfTemplate(pairs)
    times: dict[str, list[float]] = {"joint transforms (numpy)": [], "/tf template": [],
                                     "/tf rebuilt by rosbags": [], "Odometry (rosbags)": []}
    laps = list(times.values())
    for _ in range(ENCODES // 5):
        t0 = time.perf_counter_ns()
        wxyz, xyz = frames.transforms(frames.q_from(st.joint_names, st.q))
        base_xyz, base_xyzw = rm.planar(0.0, 0.0, 0.0)
        all_xyz = np.vstack([base_xyz, xyz[moving]])
        all_xyzw = np.vstack([base_xyzw, wxyz[moving][:, [1, 2, 3, 0]]])
        t1 = time.perf_counter_ns()
        template.encode(st.stamp_ns, all_xyz, all_xyzw)
        t2 = time.perf_counter_ns()
        rz.serialize(rm.tf_message([rm.transform(p, c, all_xyz[k], all_xyzw[k], st.stamp_ns)
                                    for k, (p, c) in enumerate(pairs)]), rm.TF_MESSAGE)
        t3 = time.perf_counter_ns()
        rz.serialize(rm.odometry("odom", "b/base", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                                 st.stamp_ns), rm.ODOMETRY)
        t4 = time.perf_counter_ns()
        for lap, (start, end) in zip(laps, ((t0, t1), (t1, t2), (t2, t3), (t3, t4)),
                                     strict=True):
            lap.append((end - start) / 1e3)
    print(f"the frames the bridge adds per state, {len(pairs)} transforms")
    for name, lap in times.items():
        print(f"  {name:31s}  p50 {pct(lap, 50):7.1f} us  p99 {pct(lap, 99):7.1f} us"
              f"  ({pct(lap, 50) / mb:.0f}x the msgspec encode)")
    print(f"  /tf template is {pct(laps[2], 50) / pct(laps[1], 50):.1f}x quicker than rebuilt")

def relay(hub: zenoh.Session, endpoint: str, key_in: str, key_out: str,
          bridge: bool) -> list[float]:
    """Latencies (us) from putting a RobotState on ``key_in`` to its arrival on ``key_out``."""
    from kinesphere.clients.ros2.bridge import Bridge

    got: list[float] = []
    arrived = threading.Semaphore(0)

    def on_out(sample: zenoh.Sample) -> None:
        got.append(time.time_ns())
        arrived.release()

    with zconfig.session(config=zconfig.loopback_config(endpoint)) as middle, \
            zconfig.session(config=zconfig.loopback_config(endpoint)) as ros:
        relay_bridge: Bridge | None = None
        forwarder: zconfig.Undeclarable | None = None
        if bridge:
            relay_bridge = Bridge(middle, KEYS)
        else:
            out = middle.declare_publisher(key_out)
            forwarder = middle.declare_subscriber(key_in, lambda s: out.put(s.payload))
        sub = ros.declare_subscriber(key_out, on_out)
        pub = hub.declare_publisher(key_in)
        zconfig.wait_matching(pub)
        sent: list[int] = []
        pub.put(encode(state("baxter", 0)))  # the bridge declares its publishers on the first
        if not arrived.acquire(timeout=10):
            raise RuntimeError(f"nothing arrived on {key_out}")
        got.clear()
        for i in range(1, RELAYED + 1):
            sent.append(time.time_ns())
            pub.put(encode(state("baxter", i)))
            if not arrived.acquire(timeout=5):
                raise RuntimeError(f"message {i} lost on {key_out}")
            time.sleep(SPACING_S)
        zconfig.undeclare(sub, pub)
        if relay_bridge is not None:
            relay_bridge.close()
        zconfig.undeclare(forwarder)
    return [(g - s) / 1e3 for s, g in zip(sent, got, strict=True)]


def bench_relay() -> None:
    # no databank here, so no body: the bridge relays joint states only (and says so once)
    logging.getLogger("kinesphere.clients.ros2.bridge").setLevel(logging.ERROR)
    with zconfig.loopback_hub() as (hub, endpoint):
        key_in = KEYS.state("bench-1")
        base = relay(hub, endpoint, key_in, "ros2bench/echo", bridge=False)
        ros_key = rz.topic_key(0, "/bench_1/joint_states", rm.JOINT_STATE)
        ours = relay(hub, endpoint, key_in, ros_key, bridge=True)
    mb, mo = pct(base, 50), pct(ours, 50)
    print(f"relay latency, RobotState put -> delivered, {RELAYED} states, loopback")
    print(f"  bare relay (same bytes)          p50 {mb:7.1f} us  p99 {pct(base, 99):7.1f} us")
    print(f"  ros2 bridge (JointState)         p50 {mo:7.1f} us  p99 {pct(ours, 99):7.1f} us"
          f"  ({mo / mb:.2f}x the bare relay)")


def main() -> None:
    bench_encode()
    bench_relay()


if __name__ == "__main__":
    main()
