"""URDFs from elsewhere: read within bounds, checked whole, mended where the mend is standard.

A URDF brought by a user (or a hostile package) is read as bytes of bounded size, its tree
bounded in links and joints, every number checked finite and the tree checked to be one tree
(one root, no link with two parents, no cycle) before any tool builds on it. What simulators
accept but MuJoCo or the eURDF loader would not is mended when the mend is safe and is what
other readers do, and every mend is said in one line (:class:`Mends`):

* stray bytes around the XML (whitespace before the declaration, trailing NULs) are dropped;
* a pybullet ``spherical`` joint becomes three revolutes about x, y, z through two massless
  links (Bullet's swing and twist limits on the axes; no limit: continuous);
* a revolute whose lower limit is not below its upper one is unlimited (Bullet's rule), one
  without limits continuous;
* a mesh ``scale`` with more than three numbers keeps the first three (as pybullet reads it);
* a pybullet ``capsule`` becomes a cylinder and a sphere at each end (the same shape);
* xacro's ``$(optenv NAME DEFAULT)`` left in an attribute reads as its default;
* geometry of zero or negative size, which MuJoCo refuses, is dropped (it covers nothing);
* a root link without geometry holding its robot by one floating or planar joint, or a
  ``world`` link welding it, is ROS's way of freeing or fixing a base: it goes (its child is
  the root; floating or planar makes the base mobile); a root named ``world`` on any other
  joint is renamed, since MuJoCo reserves the name.

Anything else (a floating joint inside the tree, a cycle, a NaN, a zero axis) is refused
with one line naming the element.
"""

from __future__ import annotations

import copy
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from kinesphere.eurdf import MAX_LINKS, robot_root
from kinesphere.labels import invalid

MAX_BYTES = 16 * 2**20  # a URDF file; the largest real ones are a few hundred KB
NUMERIC = frozenset({
    "xyz", "rpy", "value", "ixx", "ixy", "ixz", "iyy", "iyz", "izz", "lower", "upper",
    "effort", "velocity", "size", "radius", "length", "scale", "multiplier", "offset",
    "damping", "friction", "rgba", "soft_lower_limit", "soft_upper_limit", "k_position",
    "k_velocity", "rising", "falling", "twist",
})
GEOMETRY_SIZES = {"box": ("size",), "cylinder": ("radius", "length"), "sphere": ("radius",),
                  "capsule": ("radius", "length")}
RESERVED_ROOT = "world"  # MuJoCo's own world body


@dataclass
class Mends:
    """What was changed to make a URDF readable, one line each, and what the mends imply."""

    lines: list[str] = field(default_factory=list)
    mobile_root: str | None = None  # the floating/planar joint a dropped world root had

    def add(self, line: str) -> None:
        self.lines.append(line)


def read_bytes(path: Path) -> bytes:
    """A URDF file's bytes, refused past MAX_BYTES before anything is read."""
    if not path.is_file():
        raise invalid(f"URDF file not found: {path}")
    size = path.stat().st_size
    if size > MAX_BYTES:
        raise invalid(f"{path}: {size} bytes; a URDF may have at most {MAX_BYTES}")
    with path.open("rb") as fh:
        return fh.read(MAX_BYTES + 1)[:MAX_BYTES]


def parse(data: bytes, source: str, mends: Mends) -> ET.Element:
    """The ``<robot>`` element of URDF bytes, stray bytes around the XML dropped (and said)."""
    trimmed = data.lstrip(b"\xef\xbb\xbf").strip(b" \t\r\n\x00")
    if trimmed != data.lstrip(b"\xef\xbb\xbf").rstrip(b" \t\r\n"):
        mends.add("stray bytes around the XML (whitespace before it, NULs after it) dropped")
    return robot_root(trimmed, source)


def check(root: ET.Element) -> None:
    """Bounds, finite numbers and one tree; raises naming the first offending element."""
    links = root.findall("link")
    joints = root.findall("joint")
    if not links:
        raise invalid("it has no <link>: nothing to label")
    if len(links) > MAX_LINKS or len(joints) > MAX_LINKS:
        raise invalid(f"{len(links)} links and {len(joints)} joints; a robot may have at most "
                      f"{MAX_LINKS} of each")
    for el in root.iter():
        for attr, value in el.attrib.items():
            if attr in NUMERIC and not all(_finite(x) for x in value.split()):
                owner = _owner(root, el)
                raise invalid(f"{owner}: <{el.tag} {attr}={value!r}> is not a finite number")
    _check_tree(root)


def _finite(token: str) -> bool:
    try:
        return math.isfinite(float(token))
    except ValueError:
        return True  # not a number at all: the URDF reader names that itself


def _owner(root: ET.Element, target: ET.Element) -> str:
    for kind in ("link", "joint"):
        for el in root.findall(kind):
            if any(x is target for x in el.iter()):
                return f"<{kind} name={el.get('name')!r}>"
    return "<robot>"


def _check_tree(root: ET.Element) -> None:
    names: set[str] = set()
    for i, el in enumerate(root.findall("link")):
        name = el.get("name")
        if not name:
            raise invalid(f"<link> number {i + 1} has no name")
        if name in names:
            raise invalid(f"<link name={name!r}> appears twice")
        names.add(name)
    parent_of: dict[str, str] = {}
    children: dict[str, list[str]] = {}
    joint_names: set[str] = set()
    for el in root.findall("joint"):
        jn = el.get("name")
        if not jn:
            raise invalid("a <joint> has no name")
        if jn in joint_names:
            raise invalid(f"<joint name={jn!r}> appears twice")
        joint_names.add(jn)
        ends = []
        for tag in ("parent", "child"):
            ref = el.find(tag)
            target = ref.get("link") if ref is not None else None
            if not target or target not in names:
                raise invalid(f"<joint name={jn!r}> has no existing <{tag} link=...>")
            ends.append(target)
        parent, child = ends
        if child in parent_of:
            raise invalid(f"link {child!r} is the child of joints {parent_of[child]!r} and "
                          f"{jn!r}; a URDF is a tree")
        parent_of[child] = jn
        children.setdefault(parent, []).append(child)
    roots = [n for n in names if n not in parent_of]
    if len(roots) != 1:
        what = "none: the joints form a cycle" if not roots else ", ".join(sorted(roots)[:4])
        raise invalid(f"a URDF has exactly one root link; found {what}")
    seen, todo = set(), [roots[0]]
    while todo:
        link = todo.pop()
        seen.add(link)
        todo.extend(children.get(link, []))
    cycle = sorted(names - seen)
    if cycle:
        raise invalid(f"links {', '.join(cycle[:4])} form a kinematic cycle; a URDF is a tree")


def mend(root: ET.Element, mends: Mends) -> None:
    """Mend what other readers accept and MuJoCo or the eURDF loader would not (see module)."""
    _optenv(root, mends)
    _capsules(root, mends)
    _spherical(root, mends)
    for el in root.findall("joint"):
        kind = el.get("type")
        name = el.get("name")
        if kind not in ("revolute", "continuous", "prismatic", "fixed", "floating", "planar"):
            raise invalid(f"<joint name={name!r}> has type {kind!r}; URDF joints are revolute, "
                          "continuous, prismatic, fixed, floating or planar")
        axis = el.find("axis")
        if kind in ("revolute", "continuous", "prismatic") and axis is not None:
            xyz = [float(x) for x in (axis.get("xyz") or "1 0 0").split()]
            if len(xyz) != 3 or math.hypot(*xyz) < 1e-9:
                raise invalid(f"<joint name={name!r}> has axis {axis.get('xyz')!r}; it needs "
                              "three numbers, not all zero")
        if kind == "revolute" and el.find("mimic") is None:
            _revolute_limits(el, mends)
        lim = el.find("limit")
        if kind == "prismatic" and lim is not None and el.find("mimic") is None:
            lower, upper = _float(lim.get("lower")), _float(lim.get("upper"))
            if lower is not None and upper is not None and lower > upper:
                raise invalid(f"<joint name={name!r}> (prismatic) has lower limit {lower:g} "
                              f"above upper {upper:g}; a URDF slider cannot be unlimited")
    for el in root.iter("mesh"):
        scale = (el.get("scale") or "").split()
        if len(scale) > 3:
            el.set("scale", " ".join(scale[:3]))
            mends.add(f"mesh {el.get('filename')}: scale {' '.join(scale)!r} read as its first "
                      "three numbers")
    _zero_sizes(root, mends)
    _world_root(root, mends)
    for el in root.findall("joint"):
        if el.get("type") in ("floating", "planar"):
            raise invalid(f"<joint name={el.get('name')!r}> is {el.get('type')} inside the tree: "
                          "only a robot's root may float (make it fixed, or the root's joint)")
    check(root)  # the mends added links and joints: still within bounds


_OPTENV = re.compile(r"^\$\(optenv\s+\S+\s*(.*)\)$")


def _optenv(root: ET.Element, mends: Mends) -> None:
    for el in root.iter():
        for attr, value in el.attrib.items():
            m = _OPTENV.match(value.strip())
            if m:
                el.set(attr, m.group(1).strip())
                mends.add(f"<{el.tag} {attr}={value!r}>: xacro's optenv read as its default "
                          f"{m.group(1).strip()!r}")


def _capsules(root: ET.Element, mends: Mends) -> None:
    """A capsule (radius r, length l along z) as a cylinder plus a sphere at each end."""
    for link in root.findall("link"):
        for kind in ("visual", "collision"):
            for item in list(link.findall(kind)):
                capsule = item.find("geometry/capsule")
                if capsule is None:
                    continue
                radius, length = capsule.get("radius", "0"), capsule.get("length", "0")
                geometry = item.find("geometry")
                assert geometry is not None
                geometry.remove(capsule)
                ET.SubElement(geometry, "cylinder", radius=radius, length=length)
                at = list(link).index(item)
                for end in (0.5, -0.5):
                    cap = copy.deepcopy(item)
                    cap_geometry = cap.find("geometry")
                    assert cap_geometry is not None
                    for child in list(cap_geometry):
                        cap_geometry.remove(child)
                    ET.SubElement(cap_geometry, "sphere", radius=radius)
                    _shift_z(cap, end * (_float(length) or 0.0))
                    at += 1
                    link.insert(at, cap)
                mends.add(f"link {link.get('name')}: {kind} capsule read as a cylinder with a "
                          "sphere at each end")


def _shift_z(item: ET.Element, dz: float) -> None:
    """Move an element's origin by ``dz`` along its own z axis."""
    origin = item.find("origin")
    if origin is None:
        origin = ET.SubElement(item, "origin", xyz="0 0 0", rpy="0 0 0")
    xyz = [float(x) for x in (origin.get("xyz") or "0 0 0").split()]
    r, p, y = [float(x) for x in (origin.get("rpy") or "0 0 0").split()]
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y),
                              math.sin(y))
    z_axis = (cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr)  # Rz Ry Rx, column z
    origin.set("xyz", " ".join(f"{a + dz * b:.9g}" for a, b in zip(xyz, z_axis, strict=True)))


def _revolute_limits(el: ET.Element, mends: Mends) -> None:
    name = el.get("name")
    lim = el.find("limit")
    lower = lim.get("lower") if lim is not None else None
    upper = lim.get("upper") if lim is not None else None
    if lower is None or upper is None:
        el.set("type", "continuous")
        mends.add(f"joint {name}: revolute without limits, read as continuous")
        return
    try:
        lo, hi = float(lower), float(upper)
    except ValueError:
        return  # the URDF reader names it
    if lo >= hi:
        el.set("type", "continuous")
        mends.add(f"joint {name}: limits [{lower}, {upper}] enclose nothing; read as unlimited "
                  "(continuous), as Bullet reads them")


def _spherical(root: ET.Element, mends: Mends) -> None:
    """Each spherical joint as three revolutes (x, y, z) through two massless links."""
    names = {el.get("name") for el in root.findall("link")} | {
        el.get("name") for el in root.findall("joint")}
    for el in list(root.findall("joint")):
        if el.get("type") != "spherical":
            continue
        name = str(el.get("name"))
        lim = el.find("limit")
        spans = {"x": "lower", "y": "upper", "z": "twist"}  # Bullet's cone-twist limits
        parent = el.find("parent")
        child = el.find("child")
        assert parent is not None and child is not None  # check() saw both
        prev = str(parent.get("link"))
        made = []
        position = list(root).index(el)
        root.remove(el)
        for k, axis in enumerate(("x", "y", "z")):
            jname = _fresh(f"{name}_{axis}", names)
            last = k == 2
            link = str(child.get("link")) if last else _fresh(f"{name}_{axis}_link", names)
            joint = ET.Element("joint", name=jname)
            span = _float(lim.get(spans[axis])) if lim is not None else None
            if span is not None and span > 0:
                joint.set("type", "revolute")
                ET.SubElement(joint, "limit", lower=f"{-span:g}", upper=f"{span:g}",
                              effort=lim.get("effort", "0") if lim is not None else "0",
                              velocity=lim.get("velocity", "0") if lim is not None else "0")
            else:
                joint.set("type", "continuous")
            ET.SubElement(joint, "parent", link=prev)
            ET.SubElement(joint, "child", link=link)
            origin = el.find("origin")
            if k == 0 and origin is not None:
                joint.append(origin)
            ET.SubElement(joint, "axis", xyz={"x": "1 0 0", "y": "0 1 0", "z": "0 0 1"}[axis])
            if not last:
                root.insert(position, ET.Element("link", name=link))
                position += 1
            root.insert(position, joint)
            position += 1
            made.append(jname)
            prev = link
        mends.add(f"joint {name}: spherical, read as three revolutes {', '.join(made)}")


def _fresh(name: str, taken: set[str | None]) -> str:
    out, n = name, 1
    while out in taken:
        n += 1
        out = f"{name}{n}"
    taken.add(out)
    return out


def _float(text: str | None) -> float | None:
    try:
        return float(text) if text is not None else None
    except ValueError:
        return None


def _zero_sizes(root: ET.Element, mends: Mends) -> None:
    for link in root.findall("link"):
        for kind in ("visual", "collision"):
            for k, item in enumerate(list(link.findall(kind))):
                geometry = item.find("geometry")
                shape = next(iter(geometry), None) if geometry is not None else None
                if shape is None:
                    continue
                sizes = [_float(x) for a in GEOMETRY_SIZES.get(shape.tag, ())
                         for x in (shape.get(a) or "1").split()]
                if shape.tag == "mesh":  # a negative scale mirrors (Talos's left and right)
                    sizes = [abs(x) if x is not None else None
                             for x in map(_float, (shape.get("scale") or "1").split())]
                if any(s is not None and s <= 0 for s in sizes):
                    link.remove(item)
                    mends.add(f"link {link.get('name')}: {kind} {k} ({shape.tag} of size 0) "
                              "dropped")


def _world_root(root: ET.Element, mends: Mends) -> None:
    children = {str(el.find("child").get("link")) for el in root.findall("joint")}  # type: ignore[union-attr]
    top = next(el for el in root.findall("link") if el.get("name") not in children)
    name = str(top.get("name"))
    held = [el for el in root.findall("joint")
            if el.find("parent").get("link") == name]  # type: ignore[union-attr]
    bare = not any(top.find(tag) is not None for tag in ("visual", "collision"))
    kinds = ("floating", "planar") + (("fixed",) if name == RESERVED_ROOT else ())
    if len(held) == 1 and bare and held[0].get("type") in kinds:
        kind = held[0].get("type")
        root.remove(held[0])
        root.remove(top)
        child = held[0].find("child").get("link")  # type: ignore[union-attr]
        if kind == "fixed":
            mends.add(f"root link {name} (welded to {child} by {held[0].get('name')}) dropped: "
                      f"{child} is the root")
        else:
            mends.mobile_root = str(held[0].get("name"))
            mends.add(f"root link {name} ({kind} joint {held[0].get('name')} to {child}) "
                      f"dropped: {child} is the root of a mobile base")
        return
    if name == RESERVED_ROOT:
        taken = {el.get("name") for el in root.findall("link")}
        new = _fresh("world_link", taken)
        top.set("name", new)
        for el in root.findall("joint"):
            ref = el.find("parent")
            if ref is not None and ref.get("link") == name:
                ref.set("link", new)
        mends.add(f"root link {name!r} renamed {new!r} (MuJoCo reserves the name); it stays "
                  "fixed to the world")
