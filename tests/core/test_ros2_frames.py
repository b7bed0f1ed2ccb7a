"""The bridge's /tf CDR, written in place into a layout rosbags made, is byte for byte what
rosbags serialises for the same message (random frames, values and stamps); its joint frames
are yourdfpy's forward kinematics."""

from __future__ import annotations

import io

import numpy as np
import yourdfpy
from rosbags.typesys import Stores, get_typestore

from kinesphere import ros2msgs as rm
from kinesphere.eurdf import plain_urdf
from kinesphere.joint_frames import JointFrames
from kinesphere.platforms.platform import load_platform
from support.urdf_fk import set_cfg


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


def test_joint_frames_are_yourdfpy_kinematics_nanoradians_apart() -> None:
    """The frames the bridge publishes (``JointFrames``) are yourdfpy's forward kinematics of
    the same URDF to 1e-12, at joint values nanoradians from 0 and from the last ones: a robot
    holding still sits there, and trimesh's scene graph, under yourdfpy, keeps a joint's old
    matrix across such small steps unless :func:`set_cfg` is used."""
    eurdf = load_platform("packbot").eurdf
    assert eurdf.path is not None
    frames = JointFrames(eurdf)
    urdf = yourdfpy.URDF.load(io.StringIO(plain_urdf(eurdf.path.read_text(encoding="utf-8"))),
                              build_scene_graph=True, load_meshes=False)
    rng = np.random.default_rng(5)
    q = np.zeros(len(frames.joint_names))
    for _ in range(6):
        q = q + rng.uniform(-5e-9, 5e-9, size=q.size)
        set_cfg(urdf, dict(zip(frames.joint_names, q.tolist(), strict=True)))
        poses = frames.link_poses(q)
        for link, pose in poses.items():
            assert np.allclose(pose, urdf.get_transform(link, frames.root), atol=1e-12), link
