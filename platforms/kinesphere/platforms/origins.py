"""URDF ``<origin xyz rpy>`` elements as 4x4 transforms and back, for edits of a URDF's frames
(the root turned so z is up, a stand-in box placed on a link's principal axes)."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF's fixed-axis roll, pitch, yaw: ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch),
                              math.sin(pitch), math.cos(yaw), math.sin(yaw))
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def matrix_rpy(rot: np.ndarray) -> tuple[float, float, float]:
    """The roll, pitch, yaw of a rotation matrix (yaw 0 at the pitch = +-90 deg singularity)."""
    pitch = math.asin(max(-1.0, min(1.0, -float(rot[2, 0]))))
    if abs(rot[2, 0]) < 1 - 1e-9:
        roll = math.atan2(float(rot[2, 1]), float(rot[2, 2]))
        yaw = math.atan2(float(rot[1, 0]), float(rot[0, 0]))
    else:
        roll, yaw = math.atan2(-float(rot[1, 2]), float(rot[1, 1])), 0.0
    return roll, pitch, yaw


def read(el: ET.Element | None) -> np.ndarray:
    """The transform of an element's ``<origin>`` child (identity when it has none)."""
    out = np.eye(4)
    origin = el.find("origin") if el is not None else None
    if origin is None:
        return out
    xyz = [float(x) for x in (origin.get("xyz") or "0 0 0").split()]
    rpy = [float(x) for x in (origin.get("rpy") or "0 0 0").split()]
    out[:3, :3] = rpy_matrix(*rpy)
    out[:3, 3] = xyz
    return out


def write(el: ET.Element, transform: np.ndarray) -> None:
    """Set (or add, first) an element's ``<origin>`` to ``transform``."""
    origin = el.find("origin")
    if origin is None:
        origin = ET.Element("origin")
        el.insert(0, origin)
    origin.set("xyz", " ".join(f"{float(v):.9g}" for v in transform[:3, 3]))
    origin.set("rpy", " ".join(f"{v:.9g}" for v in matrix_rpy(transform[:3, :3])))
