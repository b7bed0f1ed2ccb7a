"""Where a body part points, by forward kinematics of joint values on the body's eURDF.

What a robot *did* is measured from the joint states it reports, with the kinematics any URDF
reader computes (:class:`~kinesphere.joint_frames.JointFrames`, robot_state_publisher's
transforms) and nothing of the solver or databank that chose the pose: a client that has the
body's eURDF (from the databank's body model) can say where each part points. No MuJoCo, no
collision geometry: an operator's laptop carries neither.

A part is a segment from a joint location's pivot (:func:`~kinesphere.joint_frames.pivot`:
the shoulder, the elbow) to another location's pivot (the upper arm ends at the elbow), or to
the tip of a limb (its tip link's origin: the hand frame at the end of a forearm, the gaze
frame of NAO's head). Directions are in the body frame, the root link's: x forward, y left,
z up.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from kinesphere.eurdf import Eurdf
from kinesphere.joint_frames import JointFrames, pivot

Array = npt.NDArray[np.float64]


class Pointing:
    """One body's segments measured for any joint values (joint name -> value)."""

    def __init__(self, eurdf: Eurdf) -> None:
        self.eurdf = eurdf
        self.frames = JointFrames(eurdf)
        self._axes = {j.name: np.asarray(j.axis if j.axis is not None else (1.0, 0.0, 0.0),
                                         dtype=float)
                      for j in eurdf.urdf.robot.joints}
        self._child = {j.name: str(j.child) for j in eurdf.urdf.robot.joints}

    def poses(self, joints: Mapping[str, float]) -> dict[str, Array]:
        """Every link's pose in the body frame (joints not given at 0)."""
        return self.frames.link_poses(self.frames.vector(joints))

    def point(self, name: str, poses: Mapping[str, Array]) -> Array:
        """A location's pivot (a ``J`` label) or a limb's tip (an ``L`` label), body frame."""
        e = self.eurdf
        if name in e.L:
            return np.asarray(poses[e.tip_link(name)][:3, 3])
        anchors, axes = [], []
        for joint in e.origin(name).joints:
            frame = poses[self._child[joint]]
            axis = frame[:3, :3] @ self._axes[joint]
            anchors.append(frame[:3, 3])
            axes.append(axis / np.linalg.norm(axis))
        return pivot(anchors, axes)

    def directions(self, segments: Sequence[tuple[str, str]], joints: Mapping[str, float]
                   ) -> list[Array | None]:
        """Unit vectors of ``(start, end)`` segments for joint values (None: no length)."""
        poses = self.poses(joints)
        out: list[Array | None] = []
        for start, end in segments:
            v = self.point(end, poses) - self.point(start, poses)
            n = float(np.linalg.norm(v))
            out.append(np.asarray(v / n) if n > 1e-9 else None)
        return out
