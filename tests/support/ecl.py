"""For the ECL tests: the shipped databanks, forward kinematics of poses, the toy rows."""

from __future__ import annotations

from functools import cache
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from kinesphere.laban import Direction
from kinesphere.platforms.frames import pivot
from kinesphere.platforms.mjcf import PlatformModel, platform_model
from kinesphere.platforms.platform import Platform, load_platform
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.measure import tip_point
from kinesphere.services.ecl.store import PoseRow, write_databank
from kinesphere.services.ecl.vsam import load_vsam
from support.paths import TOY


@cache
def shipped(name: str) -> Ecl:
    return Ecl.open(name)


def tip_world(pm: PlatformModel, data: mujoco.MjData, limb: str) -> np.ndarray:
    body = pm.model.body(pm.platform.eurdf.tip_link(limb)).id
    point = tip_point(pm.model, body)
    return np.asarray(data.xpos[body] + data.xmat[body].reshape(3, 3) @ point)


def full(row: dict[str, Any]) -> dict[str, float]:
    """A stored row's joints and its support (a stance leg)."""
    return {**row["joints"], **row.get("support", {})}


def configure(pm: PlatformModel, joints: dict[str, float]) -> mujoco.MjData:
    data = mujoco.MjData(pm.model)
    data.qpos[:] = pm.qpos(joints)  # neutral elsewhere, mimic joints following their leaders
    mujoco.mj_kinematics(pm.model, data)
    return data


def origin_of(pm: PlatformModel, neutral: mujoco.MjData, origin: str) -> np.ndarray:
    """The pivot of a joint location at neutral: where its directions are measured from."""
    return pivot(pm.model, neutral, pm.platform.eurdf.origin(origin).joints)


def gaze(name: str, joints: dict[str, float]) -> np.ndarray:
    """NAO's gaze in the body frame: the head's x axis (the cameras look along it)."""
    pm = platform_model(name)
    data = configure(pm, joints)
    rot = data.xmat[pm.model.body(pm.platform.eurdf.root_link).id].reshape(3, 3)
    return np.asarray(rot.T @ data.xmat[pm.model.body("Head").id].reshape(3, 3)[:, 0])


def toy_rows(offset: float = 0.0) -> list[PoseRow]:
    """Hand-made poses: every pull of limb_11 and limb_12, one direction of the tail."""
    rows = []
    for i, d in enumerate(Direction.pulls()):
        for s in (1, 2, 3):
            rows.append(PoseRow("limb_11", "distal_11", d.slug, s, {
                "yaw": 0.05 * s * (i % 7 - 3) + offset, "elbow": 0.3 + 0.1 * s + 0.01 * i,
                "wrist": -0.04 * s * (i % 5 - 2)}, cosine=0.9, reach=s / 3, margin=0.1))
            rows.append(PoseRow("forearm", "elbow_loc", d.slug, s, {
                "elbow": 0.3 - 0.1 * s - 0.01 * i, "wrist": 0.03 * s * (i % 3 - 1)}))
    rows += [PoseRow("limb_21", "distal_21", "left-middle", s, {"tail_joint": 0.5 * s})
             for s in (1, 2, 3)]
    return rows


def build(path: Path, plat: Platform | None = None, rows: list[PoseRow] | None = None) -> str:
    plat = plat or load_platform(str(TOY))
    return write_databank(path, plat, load_vsam(plat), toy_rows() if rows is None else rows,
                          "test-1")
