"""The bridge's /tf CDR, written in place into a layout rosbags made, is byte for byte what
rosbags serialises for the same message (random frames, values and stamps)."""

from __future__ import annotations

import numpy as np
from rosbags.typesys import Stores, get_typestore

from kinesphere import ros2msgs as rm


def test_tf_template_is_rosbags_serialisation() -> None:
    jazzy = get_typestore(Stores.ROS2_JAZZY)  # a store of its own, not kinesphere's
    rng = np.random.default_rng(3)
    g = "geometry_msgs/msg/"
    for n in (1, 2, 15, 40):
        pairs = [(f"r/link_{'x' * int(rng.integers(0, 9))}{k}", f"r/c{k}{'y' * (k % 5)}")
                 for k in range(n)]
        template = rm.TfTemplate(pairs)
        for stamp in (0, 1_796_000_000_123_456_789, 2**31 * 1_000_000_000 - 1):
            xyz = rng.normal(size=(n, 3)) * 10
            q = rng.normal(size=(n, 4))
            q /= np.linalg.norm(q, axis=1)[:, None]
            sec, nanosec = divmod(stamp, 1_000_000_000)
            t = jazzy.types
            expected = jazzy.serialize_cdr(t["tf2_msgs/msg/TFMessage"](transforms=[
                t[f"{g}TransformStamped"](
                    header=t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](
                        sec=sec, nanosec=nanosec), frame_id=p), child_frame_id=c,
                    transform=t[f"{g}Transform"](
                        translation=t[f"{g}Vector3"](x=xyz[k, 0], y=xyz[k, 1], z=xyz[k, 2]),
                        rotation=t[f"{g}Quaternion"](x=q[k, 0], y=q[k, 1], z=q[k, 2],
                                                     w=q[k, 3])))
                for k, (p, c) in enumerate(pairs)]), "tf2_msgs/msg/TFMessage",
                little_endian=True)
            assert template.encode(stamp, xyz, q) == bytes(expected), (n, stamp)
