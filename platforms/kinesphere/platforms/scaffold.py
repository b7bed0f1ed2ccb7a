"""``kinesphere platform new``: a platform folder for a robot brought as any URDF.

The folder holds what a shipped platform holds, proposed rather than hand-made: the eURDF
(the labeller's proposal, meshes copied beside it), ``platform.toml`` (base kind inferred,
neutral pose, base height from the geometry), ``vsam.toml`` (Laban-27 for every limb from its
own joint location; hands and grippers left for the super-user to enable). Everything is
meant to be edited by hand; every later command checks it again when it loads the folder.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from kinesphere.cliargs import MERGE_DISTANCE_M
from kinesphere.errors import KinesphereError
from kinesphere.eurdf import Eurdf, load_eurdf
from kinesphere.labeller import propose, propose_eurdf, read_urdf
from kinesphere.labeller_names import is_drive_name
from kinesphere.platforms.meshes import import_meshes
from kinesphere.platforms.platform import BaseSpec, Platform, platform_names

_NAME = re.compile(r"^[a-z][a-z0-9_-]{0,31}$")
NEUTRAL_MARGIN = 0.05  # rad (or m) between the neutral pose and any joint limit
CLEARANCE = 0.0005  # metres between the lowest geometry at neutral and the floor
MOBILE_DEFAULTS = {  # documented starting points for a wheeled or floating base: edit them
    "max_speed": 0.5, "max_yaw_rate": 1.0, "max_acceleration": 1.0, "max_jerk": 5.0,
}


@dataclass(frozen=True)
class Scaffold:
    """What ``new_platform`` wrote, for the command to report."""

    folder: Path
    eurdf: Eurdf
    base_kind: str
    height: float
    meshes_copied: int
    meshes_hulled: int
    meshes_missing: list[str]
    limbs: list[str]
    hands: list[str]


def new_platform(
    name: str, urdf: Path, parent: Path, merge_distance: float = MERGE_DISTANCE_M,
    force: bool = False,
) -> Scaffold:
    """Write ``parent/name/`` from a URDF; refuse to overwrite unless ``force``."""
    if not _NAME.match(name):
        raise KinesphereError(
            "malformed", f"platform name {name!r}: use 1-32 of a-z 0-9 _ -, starting with a letter"
        )
    if name in platform_names():
        raise KinesphereError("conflict", f"{name!r} is already a platform; pick another name")
    folder = parent / name
    if (folder / "platform.toml").exists() and not force:
        raise KinesphereError("conflict", f"{folder} already holds a platform (--force replaces)")
    folder.mkdir(parents=True, exist_ok=True)
    robot_el, urdf_model = read_urdf(urdf)
    proposal = propose(urdf_model, merge_distance)
    text = propose_eurdf(urdf, merge_distance)
    robot = ET.fromstring(text)
    robot.set("name", name)
    copied, hulls, missing = import_meshes(robot, urdf.resolve().parent, folder)
    for plugin in robot.findall("gazebo") + robot.findall("transmission"):
        robot.remove(plugin)  # simulator and controller plumbing: not part of the body
    _drop_world_link(robot)
    ET.indent(robot)
    eurdf_path = folder / f"{name}.eurdf"
    eurdf_path.write_text(
        f"<?xml version=\"1.0\"?>\n<!-- proposed by 'kinesphere platform new' from {urdf.name}:"
        " edit the body_part labels freely, then check with 'kinesphere describe' -->\n"
        + ET.tostring(robot, encoding="unicode") + "\n",
        encoding="utf-8",
    )
    eurdf = load_eurdf(eurdf_path)
    kind = _base_kind(robot_el, eurdf)
    neutral = _neutral(eurdf)
    height = _height(name, folder, eurdf, neutral)
    (folder / "platform.toml").write_text(
        _platform_toml(name, urdf, kind, height, neutral), encoding="utf-8"
    )
    limbs = [p.name for p in eurdf.limbs if p.name not in proposal.hands]
    (folder / "vsam.toml").write_text(
        _vsam_toml(eurdf, limbs, proposal.hands, kind != "fixed"), encoding="utf-8"
    )
    return Scaffold(folder, eurdf, kind, height, copied, hulls, missing, limbs, proposal.hands)


def _drop_world_link(robot: ET.Element) -> None:
    """A root link named ``world`` welded to the robot is ROS's way of fixing a base; MuJoCo
    has its own world (and reserves the name), so the weld goes and its child is the root."""
    welds = [j for j in robot.findall("joint") if j.find("parent") is not None
             and j.find("parent").get("link") == "world"]  # type: ignore[union-attr]
    if len(welds) != 1 or welds[0].get("type") != "fixed":
        return
    robot.remove(welds[0])
    for el in robot.findall("link"):
        if el.get("name") == "world":
            robot.remove(el)
    for part in robot.findall("body_part"):
        for el in part.findall("link"):
            if el.get("name") == "world":
                part.remove(el)


def _base_kind(robot: ET.Element, eurdf: Eurdf) -> str:
    """fixed, unless the URDF has a floating or planar joint or drive wheels in its core."""
    types = {el.get("type") for el in robot.findall("joint")}
    if types & {"floating", "planar"}:
        return "omni"
    core = {ln for p in eurdf.core for ln in p.links}
    wheels = [
        j for j in eurdf.urdf.robot.joints
        if j.name in eurdf.limits and j.child in core and is_drive_name(j.name)
    ]
    return "diff" if wheels else "fixed"


def _neutral(eurdf: Eurdf) -> dict[str, float]:
    """Zero, kept NEUTRAL_MARGIN inside each joint's limits: a pose at a limit leaves the
    ECL's IK (which keeps its own margin) no feasible first step, and a robot no room."""
    out: dict[str, float] = {}
    for name, lim in eurdf.limits.items():
        if not (math.isfinite(lim.lower) and math.isfinite(lim.upper)):
            continue
        value = lim.clamp(0.0, min(NEUTRAL_MARGIN, (lim.upper - lim.lower) / 4))
        if value != 0.0:
            out[name] = round(value, 6)
    return out


def _height(name: str, folder: Path, eurdf: Eurdf, neutral: dict[str, float]) -> float:
    """How high the root must sit for the lowest geometry at neutral to clear the floor."""
    from kinesphere.platforms.mjcf import build_spec

    base = BaseSpec("fixed", 0.0, 0.0, 0.0, 0.0, 0.0)
    plat = Platform(name, name, folder, eurdf, base, 4.0, 40.0, neutral)
    model = build_spec(plat).compile()
    data = mujoco.MjData(model)
    for joint, value in neutral.items():
        data.qpos[model.jnt_qposadr[model.joint(joint).id]] = value
    mujoco.mj_forward(model, data)
    lowest = 0.0
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    for g in range(model.ngeom):
        if model.geom_bodyid[g] == 0:
            continue  # the floor
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:]
        corners = (centre + signs * half) @ data.geom_xmat[g].reshape(3, 3).T + data.geom_xpos[g]
        lowest = min(lowest, float(corners[:, 2].min()))
    return round(-lowest + CLEARANCE, 4)


def _platform_toml(
    name: str, urdf: Path, kind: str, height: float, neutral: dict[str, float]
) -> str:
    speeds = MOBILE_DEFAULTS if kind != "fixed" else dict.fromkeys(MOBILE_DEFAULTS, 0.0)
    lines = [
        f"# Proposed by 'kinesphere platform new {name} --urdf {urdf.name}'. Edit freely:",
        "# the title, the base (kind fixed | omni | diff | skid and its limits), the joint",
        "# motion limits and above all the neutral pose (Place Middle) every pull starts from.",
        "[platform]",
        f'name = "{name}"',
        f'title = "{name} (brought from {urdf.name})"',
        f'eurdf = "{name}.eurdf"',
        "",
        "[base]",
        f'kind = "{kind}"' + ("" if kind == "fixed" else "    # inferred: check it"),
        f"height = {height}     # root above the floor: lowest geometry at neutral clears it",
        *(f"{k} = {v}" for k, v in speeds.items()),
        "",
        "[motion]",
        "max_acceleration = 3.0    # rad/s^2, all joints",
        "max_jerk = 30.0           # rad/s^3",
        "",
        "[neutral]                 # joints not listed sit at 0",
        *(f"{j} = {v}" for j, v in neutral.items()),
    ]
    return "\n".join(lines) + "\n"


def _vsam_toml(eurdf: Eurdf, limbs: list[str], hands: list[str], mobile: bool) -> str:
    lines = [
        f"# VSAM (k_o, k_d, k_s) of {eurdf.name}: the paper's Laban-27 instantiation, every",
        "# limb from its own joint location. Delete entries you do not want; hands and",
        "# grippers are listed commented out. 'kinesphere ecl build FOLDER' generates the ECL.",
        "sizes = [1, 2, 3]",
        'directions = "laban-27"',
        "translation_step = 0.25   # metres per size unit past far" if mobile
        else "# fixed base: no translation_step; sizes past far are an error",
    ]
    aliases = {p.name: p.alias for p in eurdf.limbs}
    for limb in [*limbs, *hands]:
        mark = "# " if limb in hands else ""
        origin = "distal_" + limb.split("_", 1)[1]
        lines += [
            "",
            f"{mark}[[entry]]",
            f'{mark}limb = "{limb}"' + (f"   # {aliases[limb]}" if aliases.get(limb) else ""),
            f'{mark}origin = "{origin}"',
        ]
    return "\n".join(lines) + "\n"
