"""Where a spatial command is measured from: the pivot of a joint location, in MuJoCo.

A joint location (``distal_ij``) groups the joints a limb turns about there: a shoulder's pitch
and roll, a wrist's three axes, NAO's hip. The paper measures a direction from the origin, so
the origin is the point the limb turns about (:func:`kinesphere.joint_frames.pivot`: nearest
to all of the group's joint axes, at the neutral pose). This reads the axes from a MuJoCo
model's data; the core's function does the geometry, for the eURDF's kinematics as well.
"""

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np

from kinesphere.joint_frames import PIVOT_REACH
from kinesphere.joint_frames import pivot as nearest_pivot

__all__ = ["PIVOT_REACH", "pivot"]


def pivot(model: mujoco.MjModel, data: mujoco.MjData, joints: Sequence[str]) -> np.ndarray:
    """The world point the joints' axes meet at (``data`` after kinematics), see the module."""
    anchors = [data.xanchor[model.joint(j).id].copy() for j in joints]
    axes = [data.xaxis[model.joint(j).id].copy() for j in joints]
    return nearest_pivot(anchors, axes)
