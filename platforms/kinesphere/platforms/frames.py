"""Where a spatial command is measured from: the pivot of a joint location.

A joint location (``distal_ij``) groups the joints a limb turns about there: a shoulder's pitch
and roll, a wrist's three axes, NAO's hip. The paper measures a direction from the origin, so
the origin is the point the limb turns about: the point nearest to all of the group's joint
axes (least squares, at the neutral pose). Baxter's elbow group starts with the ``e0`` roll
27 cm before the elbow bend ``e1``; its pivot is at the elbow, where a person would put it.
When the axes do not meet (within PIVOT_REACH, e.g. two parallel pitch joints of a planar
arm) or the group has one joint, the origin stays at the first joint's anchor.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

PIVOT_REACH = 0.05
"""metres: the pivot must lie this close to every axis of its group, else the first anchor."""
_PULL = 1e-6  # a whisper toward the first anchor: picks the point on a lone or shared axis


def pivot(model: mujoco.MjModel, data: mujoco.MjData, joints: Sequence[str]) -> np.ndarray:
    """The world point the joints' axes meet at (``data`` after kinematics), see the module."""
    anchors = [data.xanchor[model.joint(j).id].copy() for j in joints]
    axes = [data.xaxis[model.joint(j).id].copy() for j in joints]
    first = anchors[0]
    if len(joints) < 2:
        return np.asarray(first)
    lhs, rhs = _PULL * np.eye(3), _PULL * first
    for p, a in zip(anchors, axes, strict=True):
        proj = np.eye(3) - np.outer(a, a)
        lhs += proj
        rhs += proj @ p
    point = np.linalg.solve(lhs, rhs)
    far = max(_distance_to_axis(point, p, a) for p, a in zip(anchors, axes, strict=True))
    return np.asarray(point if far <= PIVOT_REACH else first)


def _distance_to_axis(x: np.ndarray, p: np.ndarray, a: np.ndarray) -> float:
    v = x - p
    return float(np.linalg.norm(v - (v @ a) * a))
