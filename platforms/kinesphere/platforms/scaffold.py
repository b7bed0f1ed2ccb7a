"""``kinesphere platform new``: a platform folder for a robot brought as any URDF.

The folder holds what a shipped platform holds, proposed rather than hand-made: the eURDF
(the labeller's proposal, meshes copied beside it, every mend made to the URDF in a comment),
``platform.toml`` (base kind inferred from what the robot stands on, base height from its
collision geometry, a neutral pose that leaves its limbs their directions), ``vsam.toml``
(Laban-27 for every limb from its own joint location; hands and grippers left for the
super-user to enable). Everything is meant to be edited by hand; every later command checks it
again when it loads the folder.

The folder is written whole or not at all: into a hidden folder beside it, checked by loading
it as a platform and compiling it with MuJoCo, then renamed into place (the old folder, with
``--force``, goes only then). Nothing is created before the URDF has been read; a third-party
URDF is bounded (bytes, links, joints, mesh sizes, time), and what it needs mended is mended
and said (:mod:`kinesphere.urdfmend`, :mod:`kinesphere.platforms.meshes`).
"""

from __future__ import annotations

import copy
import io
import json
import os
import re
import shutil
import stat
import tempfile
import time
import warnings
import xml.etree.ElementTree as ET
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np
import yourdfpy

from kinesphere import hints
from kinesphere.cliargs import MERGE_DISTANCE_M
from kinesphere.errors import KinesphereError
from kinesphere.eurdf import ACTUATED_TYPES, Eurdf, load_eurdf
from kinesphere.labeller import Proposal, link_frames, propose, read_urdf, xml_comment
from kinesphere.labeller_names import is_wheel_name
from kinesphere.platforms import neutral as neutral_search
from kinesphere.platforms import stance
from kinesphere.platforms.meshes import Imported, import_meshes
from kinesphere.platforms.platform import BaseSpec, Platform, load_platform, platform_names
from kinesphere.urdfmend import Mends

_NAME = re.compile(r"^[a-z][a-z0-9]*(?:[_-][a-z0-9]+)*$")
MAX_NAME = 32
NEUTRAL_MARGIN = 0.05  # rad (or m) between the neutral pose and any joint limit
CLEARANCE = 0.0005  # metres between the lowest collision geometry at neutral and the floor
TIME_LIMIT = 120.0  # seconds one 'platform new' may take
MOBILE_DEFAULTS = {  # documented starting points for a wheeled or floating base: edit them
    "max_speed": 0.5, "max_yaw_rate": 1.0, "max_acceleration": 1.0, "max_jerk": 5.0,
}
LEGGED_DEFAULTS = {  # walking abstracted: slower than wheels
    "max_speed": 0.2, "max_yaw_rate": 0.5, "max_acceleration": 0.5, "max_jerk": 2.0,
}


@dataclass
class Scaffold:
    """What ``new_platform`` wrote, for the command to report."""

    folder: Path
    eurdf: Eurdf
    base_kind: str
    height: float
    meshes: Imported
    limbs: list[str]
    hands: list[str]
    mends: list[str] = field(default_factory=list)
    neutral: list[neutral_search.Proposal] = field(default_factory=list)
    standing_on: list[str] = field(default_factory=list)
    up: str = "z"
    warnings: str | None = None  # third-party warnings, one line
    knees: dict[str, float] = field(default_factory=dict)  # straight standing legs, bent


class _Clock:
    """The time bound of one run, checked between its steps."""

    def __init__(self, limit: float) -> None:
        self.limit = limit
        self.start = time.monotonic()

    def check(self, step: str) -> None:
        if time.monotonic() - self.start > self.limit:
            raise KinesphereError("invalid_eurdf", f"platform new took more than "
                                  f"{self.limit:g} s (at {step}); the robot is too large")


def check_name(name: str) -> None:
    """A platform name is a folder name, a TOML string and part of XML: keep it plain."""
    if len(name) > MAX_NAME or not _NAME.match(name):
        raise KinesphereError(
            "malformed", f"platform name {name!r}: use 1-{MAX_NAME} of a-z 0-9, words joined by "
            "single _ or -, starting with a letter")
    if name in platform_names():
        raise KinesphereError("conflict", f"{name!r} is already a platform; pick another name")


def new_platform(
    name: str, urdf: Path, parent: Path, merge_distance: float = MERGE_DISTANCE_M,
    force: bool = False, up: str = "auto", neutral: str = "auto", time_limit: float = TIME_LIMIT,
) -> Scaffold:
    """Write ``parent/name/`` from a URDF, whole or not at all; refuse to replace an existing
    folder unless ``force``. ``up``: the file's up axis (x, y, z, -x, -y, -z) or auto (from
    its legs); ``neutral``: auto (propose a bent pose where zero is singular) or zero."""
    check_name(name)
    if up != "auto" and up not in stance.UP_AXES:
        raise KinesphereError("malformed", f"--up {up!r}: use auto or one of "
                              f"{', '.join(stance.UP_AXES)}")
    clock = _Clock(time_limit)
    mends = Mends()
    robot_el, model = read_urdf(urdf, mends)  # nothing is created before this succeeds
    if not any(j.type in ACTUATED_TYPES and j.mimic is None for j in model.robot.joints):
        raise KinesphereError("invalid_eurdf", f"{urdf}: nothing to steer: no revolute, "
                              "continuous or prismatic joint (an object, not a robot)")
    folder = parent / name
    if folder.exists() and not force:
        if (folder / "platform.toml").exists():
            raise KinesphereError("conflict", f"{folder} already holds a platform "
                                  "(--force replaces it)")
        if not folder.is_dir() or any(folder.iterdir()):
            raise KinesphereError("conflict", f"{folder} exists and is not an empty folder")
    parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(parent, name)
    work = Path(tempfile.mkdtemp(prefix=f".{name}.{os.getpid()}.", suffix=".tmp", dir=parent))
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            made = _build(name, urdf, robot_el, model, mends, work, merge_distance, up, neutral,
                          clock)
        made.warnings = _summary(caught)
        os.chmod(work, _folder_mode(urdf))
        _swap(work, folder)
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    made.folder = folder
    return made


def _build(name: str, urdf: Path, robot_el: ET.Element, model: yourdfpy.URDF, mends: Mends,
           work: Path, merge_distance: float, up: str, neutral: str, clock: _Clock) -> Scaffold:
    mode = _file_mode(urdf)
    proposal = propose(model, merge_distance)
    clock.check("labelling")
    axis = up if up != "auto" else stance.detect_up(_leg_tips(model, proposal))
    if axis != "z":
        stance.turn_root(robot_el, stance.upright(axis))
        model = _reload(robot_el)
        proposal = propose(model, merge_distance)
        how = "detected from its legs" if up == "auto" else "--up"
        mends.add(f"turned so z is up: the file's up axis is {axis} ({how})")
    robot = copy.deepcopy(robot_el)
    robot.set("name", name)
    for old in robot.findall("body_part"):
        robot.remove(old)
    for part in proposal.elements():
        robot.append(part)
    imported = import_meshes(robot, urdf.resolve().parent, work)
    mends.lines += imported.stand_ins
    clock.check("meshes")
    for plugin in robot.findall("gazebo") + robot.findall("transmission"):
        robot.remove(plugin)  # simulator and controller plumbing: not part of the body
    from kinesphere.platforms.mjcf import unbalanced

    balanced = unbalanced(model)
    if balanced:
        mends.add(f"inertia of {', '.join(balanced[:6])}{' ...' if len(balanced) > 6 else ''} "
                  "breaks A + B >= C: evened by MuJoCo's balanceinertia")
    eurdf, compiled = _body(robot, mends, work, name, urdf, mode)
    clock.check("compiling")
    zero = _neutral(eurdf)
    qpos = _qpos(compiled, eurdf, zero)
    standing = stance.stance(compiled, qpos)
    legs, core = standing.on(eurdf)
    kind = _base_kind(eurdf, proposal, legs, core, mends)
    if kind != "fixed" and standing.drawn:  # the balance check needs what it stands on
        stance.collide_visuals(robot, standing.drawn)
        mends.add(f"{', '.join(standing.drawn)}: stand on the floor with visual shapes only; "
                  "those shapes collide too")
        eurdf, compiled = _body(robot, mends, work, name, urdf, mode)
        standing = stance.stance(compiled, qpos)
    bearing = set(legs) if kind == "legged" else set()
    knees: dict[str, float] = {}
    if bearing:  # straight standing legs bend their knees, feet kept flat
        knees = neutral_search.stance(compiled, eurdf, _qpos(compiled, eurdf, zero), legs)
        zero.update(knees)
        qpos = _qpos(compiled, eurdf, zero)
        standing = stance.stance(compiled, qpos)
    proposals: list[neutral_search.Proposal] = []
    chosen = dict(zero)
    if neutral == "auto":
        limbs = [p.name for p in eurdf.limbs if p.index[1] == 1
                 and p.name not in proposal.hands and p.name not in bearing]
        floor = float(qpos_root(compiled, qpos)) - standing.depth
        proposals = neutral_search.propose(compiled, eurdf, qpos, limbs, floor)
        for p in proposals:
            chosen.update(p.joints)
        clock.check("the neutral search")
        if chosen != zero:
            standing = stance.stance(compiled, _qpos(compiled, eurdf, chosen))
    elif neutral != "zero":
        raise KinesphereError("malformed", f"--neutral {neutral!r}: use auto or zero")
    height = round(standing.depth + CLEARANCE, 4)
    if height < 0:  # the root frame sits below every shape: the robot floats, as in the file
        mends.add(f"the root frame sits {-height:.3f} m below the lowest shape: height 0, the "
                  "robot hangs above the floor as its file places it")
        height = 0.0
        eurdf = load_eurdf(_write_eurdf(robot, mends, work, name, urdf, mode))
    _write(work / "platform.toml",
           _platform_toml(name, urdf, kind, height, chosen, zero, proposals, legs, knees,
                          work.parent / name), mode)
    limbs_kept = [p.name for p in eurdf.limbs if p.name not in proposal.hands]
    knees = knees if bearing else {}
    _write(work / "vsam.toml", _vsam_toml(eurdf, limbs_kept, proposal.hands, kind != "fixed",
                                          work.parent / name), mode)
    load_platform(str(work))  # the folder loads as a platform, neutral pose checked against P
    return Scaffold(work, eurdf, kind, height, imported, limbs_kept, proposal.hands,
                    mends.lines, proposals, legs, axis, None, knees)


def _body(robot: ET.Element, mends: Mends, work: Path, name: str, urdf: Path, mode: int
          ) -> tuple[Eurdf, mujoco.MjModel]:
    """Write the eURDF (its mends in comments), load it and compile it with a fixed base."""
    from kinesphere.platforms.mjcf import build_spec

    path = _write_eurdf(robot, mends, work, name, urdf, mode)
    eurdf = load_eurdf(path)
    plat = Platform(name, name, work, eurdf, BaseSpec("fixed", 0.0), 4.0, 40.0, {})
    try:
        return eurdf, build_spec(plat).compile()
    except ValueError as exc:  # MuJoCo's compiler: one line naming the element
        raise KinesphereError("invalid_eurdf", f"MuJoCo refuses the model: {_one_line(exc)}"
                              ) from None


def _write_eurdf(robot: ET.Element, mends: Mends, work: Path, name: str, urdf: Path,
                 mode: int) -> Path:
    """The eURDF file, each mend in a comment at the top of ``<robot>``."""
    text = copy.deepcopy(robot)
    for k, line in enumerate(mends.lines):
        text.insert(k, xml_comment(f"mended by platform new: {line}"))
    ET.indent(text)
    path = work / f"{name}.eurdf"
    path.unlink(missing_ok=True)
    _write(path, "<?xml version=\"1.0\"?>\n"
           + ET.tostring(xml_comment(f"proposed by platform new from {urdf.name}: "
                                     "edit the body_part labels freely, then check them with "
                                     "the describe command"), encoding="unicode") + "\n"
           + ET.tostring(text, encoding="unicode") + "\n", mode)
    return path


def qpos_root(model: mujoco.MjModel, qpos: np.ndarray) -> float:
    """The root's height at ``qpos`` (the root sits at height 0 while scaffolding)."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    return float(data.xpos[1, 2])


def _qpos(model: mujoco.MjModel, eurdf: Eurdf, joints: dict[str, float]) -> np.ndarray:
    q: np.ndarray = model.qpos0.copy()
    for joint, value in eurdf.with_mimics(joints).items():
        q[model.jnt_qposadr[model.joint(joint).id]] = value
    return q


def _reload(robot: ET.Element) -> yourdfpy.URDF:
    return yourdfpy.URDF.load(io.BytesIO(ET.tostring(robot)), load_meshes=False,
                              build_scene_graph=False, build_collision_scene_graph=False)


def _leg_tips(model: yourdfpy.URDF, proposal: Proposal) -> list[np.ndarray]:
    """Which way each leg hangs at zero: from its first joint to the farthest of its links
    and shapes (a link's frame may sit at its joint, its shape at the foot)."""
    children = {j.child for j in model.robot.joints}
    root = next(str(ln.name) for ln in model.robot.links if ln.name not in children)
    frames, _ = link_frames(model, root)
    tips = []
    for limb in proposal.limbs:
        if proposal.kinds.get(limb.label) != "leg":
            continue
        start = frames[limb.location.joints[0].child][:3, 3]
        points = [frames[ln][:3, 3] for ln in limb.links]
        for ln in limb.links:
            link = model.link_map[ln]
            for item in (*link.visuals, *link.collisions):
                if item.origin is not None:
                    points.append((frames[ln] @ item.origin)[:3, 3])
        tips.append(max((p - start for p in points), key=lambda p: float(np.linalg.norm(p))))
    return tips


def _base_kind(eurdf: Eurdf, proposal: Proposal, legs: list[str], core: bool,
               mends: Mends) -> str:
    """legged when two or more limbs that are no arms, heads or hands (each of two or more
    joints) and not the core stand on the floor; omni for a floating or planar root; diff for
    wheels or tracks in the core; else fixed (an arm hanging below a torso on a stand)."""
    walking = [x for x in legs if proposal.kinds.get(x) in (None, "leg")
               and x not in proposal.hands and len(eurdf.limb_joints(x)) >= 2]
    if len(walking) >= 2 and len(walking) == len(legs) and not core:
        return "legged"
    if mends.mobile_root is not None:
        return "omni"
    core_links = {ln for p in eurdf.core for ln in p.links}
    wheels = [
        j for j in eurdf.urdf.robot.joints
        if j.name in eurdf.limits and j.child in core_links and is_wheel_name(j.name)
    ]
    return "diff" if wheels else "fixed"


def _neutral(eurdf: Eurdf) -> dict[str, float]:
    """Zero, kept NEUTRAL_MARGIN inside each joint's limits, or in the middle of a range
    narrower than twice that (a gripper's 2 cm): a pose near a limit leaves the ECL's IK
    (which keeps its own margin from every limit, its limb's or not) no feasible step, and a
    robot no room. Baxter's fingers a quarter into their range froze both of its arms."""
    out: dict[str, float] = {}
    for name, lim in eurdf.limits.items():
        if not (np.isfinite(lim.lower) and np.isfinite(lim.upper)):
            continue
        value = lim.clamp(0.0, min(NEUTRAL_MARGIN, (lim.upper - lim.lower) / 2))
        if value != 0.0:
            out[name] = round(value, 6)
    return out


def _one_line(exc: Exception) -> str:
    """MuJoCo's 'Error: what\\nElement name 'x', id 3' as one line."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    what = lines[0].removeprefix("Error:").strip() if lines else type(exc).__name__
    element = next((ln for ln in lines[1:] if ln.startswith("Element name")), None)
    return f"{what} ({element.split(',')[0].lower()})" if element else what


def _summary(caught: list[warnings.WarningMessage]) -> str | None:
    """Third-party warnings as one line: how many, from whom, the commonest."""
    if not caught:
        return None
    texts = Counter(str(w.message).splitlines()[0][:100] for w in caught)
    common, count = texts.most_common(1)[0]
    return (f"{len(caught)} warnings from the mesh and model readers (most often, {count}x: "
            f"{common})")


def _file_mode(source: Path) -> int:
    """Files derived from ``source`` are never more readable than it is."""
    return stat.S_IMODE(source.stat().st_mode) & 0o644 | 0o600


def _folder_mode(source: Path) -> int:
    readable = _file_mode(source)
    return readable | (readable & 0o444) >> 2 | 0o700


def _write(path: Path, text: str, mode: int) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, mode)
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        fh.write(text)


def _swap(work: Path, folder: Path) -> None:
    """Put the finished folder in place; an old one goes only once the new one is there."""
    if not folder.exists():
        os.rename(work, folder)
        return
    old = folder.with_name(f".{folder.name}.{os.getpid()}.old.tmp")
    os.rename(folder, old)
    os.rename(work, folder)
    shutil.rmtree(old, ignore_errors=True)


def _remove_stale(parent: Path, name: str) -> None:
    """Hidden folders a killed 'platform new NAME' left beside the target (its pid is gone)."""
    for p in parent.glob(f".{name}.*.tmp"):
        pid = p.name[len(name) + 2:].split(".", 1)[0]
        if pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(p, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _toml(text: str) -> str:
    """A TOML basic string (JSON's escapes are TOML's)."""
    return json.dumps(text, ensure_ascii=False)


def _comment(text: str) -> str:
    return "".join(c if c.isprintable() else "?" for c in text)


def _commentable(text: str) -> str:
    """``text`` inside an XML comment, which may not hold ``--``."""
    return text.replace("--", "- -")


def _platform_toml(
    name: str, urdf: Path, kind: str, height: float, neutral: dict[str, float],
    zero: dict[str, float], proposals: list[neutral_search.Proposal], legs: list[str],
    knees: dict[str, float], folder: Path,
) -> str:
    speeds = {"fixed": dict.fromkeys(MOBILE_DEFAULTS, 0.0), "legged": LEGGED_DEFAULTS
              }.get(kind, MOBILE_DEFAULTS)
    lines = [
        f"# Proposed by '{hints.new_platform(name, _comment(urdf.name))}'; check the labels with",
        f"# '{hints.describe(str(folder))}'. Edit freely: the title, the base (kind fixed |",
        "# omni | diff | skid | legged and its limits),",
        "# the joint motion limits and above all the neutral pose (Place Middle) every pull",
        "# starts from.",
        "[platform]",
        f"name = {_toml(name)}",
        f"title = {_toml(f'{name} (brought from {urdf.name})')}",
        f"eurdf = {_toml(f'{name}.eurdf')}",
        "",
        "[base]",
        f'kind = "{kind}"' + ("" if kind == "fixed" else "    # inferred: check it")
        + (f" (stands on {', '.join(legs)}; walking abstracted)" if kind == "legged" else ""),
        f"height = {height}     # root above the floor: the lowest collision geometry at "
        "neutral touches it",
        *(f"{k} = {v}" for k, v in speeds.items()),
        "",
        "[motion]",
        "max_acceleration = 3.0    # rad/s^2, all joints",
        "max_jerk = 30.0           # rad/s^3",
        "",
    ]
    if knees:
        lines.append("# neutral: the standing legs were straight (a foot could not start to lift);"
                     " knees bent: " + ", ".join(f"{j} = {v:g}" for j, v in knees.items()))
    bent = [p for p in proposals if p.joints]
    for p in bent:
        lines.append(f"# neutral of {_comment(str(p))}; 'platform new --neutral zero' keeps zero")
    if bent:
        lines.append("# zero (kept off the limits) was: " + (", ".join(
            f"{j} = {v}" for j, v in zero.items()) or "every joint at 0"))
    lines += ["[neutral]                 # joints not listed sit at 0",
              *(f"{_toml(j)} = {v}" for j, v in neutral.items())]
    return "\n".join(lines) + "\n"


def _vsam_toml(eurdf: Eurdf, limbs: list[str], hands: list[str], mobile: bool, folder: Path
               ) -> str:
    lines = [
        f"# VSAM (k_o, k_d, k_s) of {eurdf.name}: the paper's Laban-27 instantiation, every",
        "# limb from its own joint location. Delete entries you do not want; hands and",
        f"# grippers are listed commented out. '{hints.build_ecl(str(folder))}' generates the",
        "# ECL.",
        "sizes = [1, 2, 3]",
        'directions = "laban-27"',
        "translation_step = 0.25   # metres per size unit past far" if mobile
        else "# fixed base: no translation_step; sizes past far are an error",
    ]
    aliases = {p.name: p.alias for p in eurdf.limbs}
    for limb in [*limbs, *hands]:
        mark = "# " if limb in hands else ""
        origin = "distal_" + limb.split("_", 1)[1]
        alias = aliases.get(limb)
        lines += [
            "",
            f"{mark}[[entry]]",
            f'{mark}limb = "{limb}"' + (f"   # {_comment(alias)}" if alias else ""),
            f'{mark}origin = "{origin}"',
        ]
    return "\n".join(lines) + "\n"
