"""eURDF: a URDF plus overlapping ``<body_part>`` labels, loaded as the paper's (C, J, L, P).

The labels sit beside the URDF elements, so any URDF tool still reads the file. A limb label
names a whole subtree, hence a link carries one label per limb that contains it; a distal label
names the joint location (one or more joints) at the root of its limb. The loader checks the
URDF part here and every label against the kinematic tree (:mod:`kinesphere.labels`), so a
broken description fails at load time with the element and the problem named, never later in
the middle of a motion.
"""

from __future__ import annotations

import hashlib
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final

from kinesphere.errors import KinesphereError
from kinesphere.labels import BodyPart, invalid, label_order, parse_part, subtree, validate
from kinesphere.urdf_tree import UrdfTree, read_urdf

ACTUATED_TYPES = ("revolute", "prismatic", "continuous")

# Bounds on a description, so that text from the wire (a databank's body answer) or a file
# costs every reader a bounded amount of work: the largest of example-robot-data's 60+
# robots (tiago_dual) has 130 links, a chain 21 deep, 223 shapes and 3,851 XML elements.
MAX_LINKS: Final = 512
"""Links in one description."""
MAX_DEPTH: Final = 64
"""Joints from the root link to the deepest one (a viewer names each link's scene node by
its whole chain, and walks it)."""
MAX_SHAPES: Final = 2048
"""``<visual>`` and ``<collision>`` elements in all."""
MAX_ELEMENTS: Final = 32_768
"""XML elements in all."""
MAX_NESTING: Final = 32
"""XML elements inside each other (a URDF nests 7 deep; serialisers recurse per level)."""
MAX_METRES: Final = 100.0
"""Largest offset or size in metres (robots are a few metres across)."""
MAX_RADIANS: Final = 100.0
"""Largest ``rpy`` angle."""
MAX_SCALE: Final = 1000.0
"""Largest mesh scale factor (meshes drawn in millimetres use 0.001)."""


@dataclass(frozen=True)
class JointLimit:
    """One axis of the configuration space P: limits in rad (or m) and rad/s (or m/s)."""

    name: str
    kind: str
    lower: float
    upper: float
    velocity: float

    def clamp(self, value: float, margin: float = 0.0) -> float:
        lo, hi = self.lower + margin, self.upper - margin
        if lo > hi:
            lo = hi = (self.lower + self.upper) / 2
        return min(max(value, lo), hi)


@dataclass(frozen=True)
class Mimic:
    """A joint driven by another (URDF ``<mimic>``): ``value = multiplier * leader + offset``.

    A mimic joint is no axis of P (one motor drives both, like NAO's hip yaw-pitch), so it is
    never commanded or stored; its value follows from its leader's.
    """

    joint: str
    leader: str
    multiplier: float
    offset: float

    def value(self, leader_value: float) -> float:
        return self.multiplier * leader_value + self.offset


@dataclass(frozen=True)
class Eurdf:
    """A loaded, validated eURDF: the platform's (C, J, L, P) plus the URDF it annotates."""

    name: str
    urdf: UrdfTree
    """The URDF part as yourdfpy reads it (:mod:`kinesphere.urdf_tree`)."""
    core: tuple[BodyPart, ...]
    distals: tuple[BodyPart, ...]
    limbs: tuple[BodyPart, ...]
    limits: dict[str, JointLimit]
    sha256: str
    path: Path | None = None
    mimics: dict[str, Mimic] = field(default_factory=dict)
    """Mimic joint -> how it follows its leader (a joint of P)."""
    _children: dict[str, list[tuple[str, str]]] = field(default_factory=dict, repr=False)

    @property
    def C(self) -> tuple[str, ...]:  # noqa: N802 - the paper's names
        return tuple(p.name for p in self.core)

    @property
    def J(self) -> tuple[str, ...]:  # noqa: N802
        return tuple(p.name for p in self.distals)

    @property
    def L(self) -> tuple[str, ...]:  # noqa: N802
        return tuple(p.name for p in self.limbs)

    @property
    def P(self) -> tuple[JointLimit, ...]:  # noqa: N802
        return tuple(self.limits.values())

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(self.limits)

    @property
    def root_link(self) -> str:
        children = {j.child for j in self.urdf.robot.joints}
        return next(str(link.name) for link in self.urdf.robot.links if link.name not in children)

    @property
    def aliases(self) -> dict[str, str]:
        return {p.alias: p.name for p in (*self.core, *self.distals, *self.limbs) if p.alias}

    def _find(self, name: str, parts: tuple[BodyPart, ...], code: str, what: str) -> BodyPart:
        key = name.strip()
        for p in parts:
            if key in (p.name, p.alias):
                return p
        valid = ", ".join(f"{p.name} ({p.alias})" if p.alias else p.name for p in parts)
        raise KinesphereError(code, f"{self.name} has no {what} {name!r}; valid: {valid or 'none'}")

    def limb(self, name: str) -> BodyPart:
        """Resolve a limb label or alias (``right_arm`` -> ``limb_11``)."""
        return self._find(name, self.limbs, "unknown_limb", "limb")

    def origin(self, name: str) -> BodyPart:
        """Resolve an origin: a distal label or alias; core labels are origins for translation."""
        return self._find(name, (*self.distals, *self.core), "unknown_origin", "origin")

    def origin_joint(self, distal: str) -> str:
        """The URDF joint whose anchor is the origin of a distal label (its first joint)."""
        return self.origin(distal).joints[0]

    def limb_joints(self, limb: str) -> tuple[str, ...]:
        """Actuated joints of a limb in P order: its distal's root joint and all below it,
        except those below its tip (a hand's fingers below an arm's palm: the arm's poses
        never move them)."""
        part = self.limb(limb)
        links = set(part.links)
        if part.tip:
            links -= set(self.subtree_links(part.tip)[1:])
        return tuple(
            j.name for j in self.urdf.robot.joints if j.name in self.limits and j.child in links
        )

    def tip_link(self, limb: str) -> str:
        """The limb's distal end: its ``tip`` attribute, else the deepest link (first on ties)."""
        part = self.limb(limb)
        if part.tip:
            return part.tip
        root = self.urdf.joint_map[self.origin_joint(str(part.distal))].child
        best, depth = root, 0
        stack = [(root, 0)]
        while stack:
            link, d = stack.pop()
            if d > depth:
                best, depth = link, d
            stack.extend((c, d + 1) for _, c in reversed(self._children.get(link, [])))
        return str(best)

    def subtree_links(self, link: str) -> list[str]:
        """``link`` and every link below it, depth first in document order."""
        return subtree(link, self._children)

    def followers(self, joint: str) -> tuple[str, ...]:
        """The mimic joints that ``joint`` drives (empty for most joints)."""
        return tuple(m.joint for m in self.mimics.values() if m.leader == joint)

    def with_mimics(self, joints: dict[str, float]) -> dict[str, float]:
        """``joints`` plus the value of every mimic joint whose leader is among them."""
        out = dict(joints)
        for m in self.mimics.values():
            if m.leader in joints:
                out[m.joint] = m.value(joints[m.leader])
        return out

    def labels_of_link(self, link: str) -> tuple[str, ...]:
        """Every label that covers a link (several for links deep in a limb)."""
        return tuple(p.name for p in (*self.core, *self.limbs) if link in p.links)


def load_eurdf(source: str | Path) -> Eurdf:
    """Load and validate an eURDF file (or XML text starting with '<')."""
    if isinstance(source, str) and source.lstrip().startswith("<"):
        text, path = source, None
    else:
        path = Path(source)
        if not path.is_file():
            raise invalid(f"eURDF file not found: {path}")
        text = path.read_text(encoding="utf-8")
    root = _robot_element(text, str(path or "eURDF"))
    name = root.get("name") or ""
    if not name:
        raise invalid("<robot> has no name attribute")
    _check_urdf_elements(root)
    try:
        urdf = read_urdf(text)
    except Exception as exc:  # yourdfpy raises assorted types for broken URDF
        raise invalid(f"URDF part is invalid: {exc}") from None
    children = _children(urdf)
    _check_tree(urdf)
    limits = _limits(urdf)
    parts = [parse_part(el) for el in root.findall("body_part")]
    validate(urdf, children, limits, parts)
    return Eurdf(
        name=name,
        urdf=urdf,
        core=tuple(sorted((p for p in parts if p.set == "C"), key=label_order)),
        distals=tuple(sorted((p for p in parts if p.set == "J"), key=label_order)),
        limbs=tuple(sorted((p for p in parts if p.set == "L"), key=label_order)),
        limits=limits,
        sha256=hashlib.sha256(text.encode("utf-8")).hexdigest(),
        path=path,
        mimics=_mimics(urdf, limits),
        _children=children,
    )


def _check_urdf_elements(root: ET.Element) -> None:
    links = [el.get("name") for el in root.findall("link")]
    if not links:
        raise invalid("<robot> has no <link>")
    if len(links) > MAX_LINKS:
        raise invalid(f"<robot> has {len(links)} links; at most {MAX_LINKS} are allowed")
    for i, link_name in enumerate(links):
        if not link_name:
            raise invalid(f"<link> number {i + 1} has no name")
    seen: set[str] = set()
    for link_name in links:
        if link_name in seen:
            raise invalid(f"<link name={link_name!r}> appears twice")
        seen.add(str(link_name))
    parent_of: dict[str, str] = {}
    for el in root.findall("joint"):
        jn = el.get("name")
        if not jn:
            raise invalid("a <joint> has no name")
        ends = {}
        for tag in ("parent", "child"):
            ref = el.find(tag)
            target = ref.get("link") if ref is not None else None
            if not target:
                raise invalid(f"<joint name={jn!r}> has no <{tag} link=...>")
            if target not in seen:
                raise invalid(f"<joint name={jn!r}> {tag} link {target!r} does not exist")
            ends[tag] = target
        if ends["child"] in parent_of:
            raise invalid(f"link {ends['child']!r} is the child of two joints; a URDF must be "
                          "a tree")
        parent_of[ends["child"]] = ends["parent"]
    _check_depth(parent_of)
    _check_numbers(root)
    for el in root.findall("joint"):
        jn = el.get("name")
        jtype = el.get("type")
        if jtype in ("revolute", "prismatic") and el.find("mimic") is None:
            lim = el.find("limit")
            if lim is None or lim.get("lower") is None or lim.get("upper") is None:
                raise invalid(f"<joint name={jn!r}> ({jtype}) needs <limit lower upper>")
            if float(lim.get("lower", "0")) > float(lim.get("upper", "0")):
                raise invalid(f"<joint name={jn!r}> has lower limit above upper limit")


def _check_depth(parent_of: dict[str, str]) -> None:
    """Every chain from the root at most :data:`MAX_DEPTH` joints long, and no cycle."""
    depth: dict[str, int] = {}
    for start in parent_of:
        chain = []
        link = start
        while link in parent_of and link not in depth:
            chain.append(link)
            if len(chain) > MAX_DEPTH + 1:
                break
            link = parent_of[link]
        if link in chain or (link in parent_of and link not in depth):
            raise invalid(f"the joints around link {start!r} form a cycle or a chain deeper "
                          f"than {MAX_DEPTH} joints")
        base = depth.get(link, 0)
        for i, member in enumerate(reversed(chain), start=1):
            depth[member] = base + i
        if depth[start] > MAX_DEPTH:
            raise invalid(f"link {start!r} is {depth[start]} joints below the root; at most "
                          f"{MAX_DEPTH} are allowed")


def _floats(el: ET.Element, attr: str, where: str, count: tuple[int, ...] = (1,),
            low: float = -math.inf, high: float = math.inf, nonzero: bool = False
            ) -> list[float]:
    """The numbers of ``el``'s attribute (empty when absent): finite, ``count`` of them,
    each within ``[low, high]`` (and not 0 when ``nonzero``), else ``invalid_eurdf``."""
    text = el.get(attr)
    if text is None:
        return []
    what = f"<{el.tag} {attr}={text!r:.60}> of {where}"
    try:
        values = [float(x) for x in text.split()]
    except ValueError:
        raise invalid(f"{what} is not a list of numbers") from None
    if len(values) not in count:
        raise invalid(f"{what} has {len(values)} numbers; "
                      f"{' or '.join(map(str, count))} expected")
    for x in values:
        if not low <= x <= high:  # also false for NaN
            raise invalid(f"{what}: {x} is not a number in [{low:g}, {high:g}]")
        if nonzero and x == 0.0:
            raise invalid(f"{what}: 0 is not allowed")
    return values


def _check_numbers(root: ET.Element) -> None:
    """Every number a URDF reader uses is finite and in range, and every shape has its
    arity (``<box size>`` three numbers, a cylinder a radius and a length...)."""
    big = MAX_METRES
    shapes = 0
    for link in root.findall("link"):
        where = f"link {link.get('name')!r}"
        parts = link.findall("visual") + link.findall("collision")
        shapes += len(parts)
        if shapes > MAX_SHAPES:
            raise invalid(f"more than {MAX_SHAPES} <visual> and <collision> elements")
        for part in (*parts, *link.findall("inertial")):
            for origin in part.findall("origin"):
                _floats(origin, "xyz", where, (3,), -big, big)
                _floats(origin, "rpy", where, (3,), -MAX_RADIANS, MAX_RADIANS)
        for part in parts:
            for geometry in part.findall("geometry"):
                for box in geometry.findall("box"):
                    if not _floats(box, "size", where, (3,), 0.0, big):
                        raise invalid(f"<box> of {where} has no size")
                for cyl in geometry.findall("cylinder"):
                    for attr in ("radius", "length"):
                        if not _floats(cyl, attr, where, (1,), 0.0, big):
                            raise invalid(f"<cylinder> of {where} has no {attr}")
                for sphere in geometry.findall("sphere"):
                    if not _floats(sphere, "radius", where, (1,), 0.0, big):
                        raise invalid(f"<sphere> of {where} has no radius")
                for mesh in geometry.findall("mesh"):
                    _floats(mesh, "scale", where, (1, 3), -MAX_SCALE, MAX_SCALE, nonzero=True)
        for inertial in link.findall("inertial"):
            for mass in inertial.findall("mass"):
                _floats(mass, "value", where, (1,), 0.0)
            for inertia in inertial.findall("inertia"):
                for attr in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"):
                    _floats(inertia, attr, where)
    for joint in root.findall("joint"):
        where = f"joint {joint.get('name')!r}"
        for origin in joint.findall("origin"):
            _floats(origin, "xyz", where, (3,), -big, big)
            _floats(origin, "rpy", where, (3,), -MAX_RADIANS, MAX_RADIANS)
        for axis in joint.findall("axis"):
            xyz = _floats(axis, "xyz", where, (3,))
            if xyz and joint.get("type") in ACTUATED_TYPES and math.hypot(*xyz) < 1e-9:
                raise invalid(f"<axis> of {where} has no direction (0 0 0)")
        for limit in joint.findall("limit"):
            _floats(limit, "lower", where)
            _floats(limit, "upper", where)
            _floats(limit, "velocity", where, (1,), 0.0)
            _floats(limit, "effort", where)
        for mimic in joint.findall("mimic"):
            _floats(mimic, "multiplier", where)
            _floats(mimic, "offset", where)
    for color in root.iter("color"):
        _floats(color, "rgba", "a <material>", (4,), 0.0, 1.0)


def _check_tree(urdf: UrdfTree) -> None:
    parent_of: dict[str, str] = {}
    for j in urdf.robot.joints:
        if j.child in parent_of:
            raise invalid(f"link {j.child!r} is the child of two joints; a URDF must be a tree")
        parent_of[j.child] = j.name
    roots = [str(link.name) for link in urdf.robot.links if link.name not in parent_of]
    if len(roots) != 1:
        raise invalid(f"a URDF has exactly one root link; found {roots or 'none (a cycle)'}")


def _children(urdf: UrdfTree) -> dict[str, list[tuple[str, str]]]:
    out: dict[str, list[tuple[str, str]]] = {}
    for j in urdf.robot.joints:
        out.setdefault(j.parent, []).append((j.name, j.child))
    return out


def _limits(urdf: UrdfTree) -> dict[str, JointLimit]:
    out: dict[str, JointLimit] = {}
    for j in urdf.robot.joints:
        if j.type not in ACTUATED_TYPES or j.mimic is not None:
            continue
        lim = j.limit
        velocity = float(lim.velocity) if lim is not None and lim.velocity else math.inf
        if j.type == "continuous":
            lower, upper = -math.inf, math.inf
        elif lim is None or lim.lower is None or lim.upper is None:  # the XML check says why
            raise invalid(f"<joint name={j.name!r}> ({j.type}) needs <limit lower upper>")
        else:
            lower, upper = lim.lower, lim.upper
        out[j.name] = JointLimit(j.name, j.type, lower, upper, velocity)
    return out


def _mimics(urdf: UrdfTree, limits: dict[str, JointLimit]) -> dict[str, Mimic]:
    out: dict[str, Mimic] = {}
    for j in urdf.robot.joints:
        if j.mimic is None or j.type not in ACTUATED_TYPES:
            continue
        if j.mimic.joint not in limits:
            continue  # a broken reference (seen in the wild): it follows nothing, as in yourdfpy
        multiplier = 1.0 if j.mimic.multiplier is None else float(j.mimic.multiplier)
        offset = 0.0 if j.mimic.offset is None else float(j.mimic.offset)
        out[j.name] = Mimic(j.name, j.mimic.joint, multiplier, offset)
    return out


def plain_urdf(text: str) -> str:
    """The URDF inside eURDF text: the same XML without its ``<body_part>`` labels, for tools
    that read URDF only and may warn about unknown elements (robot_state_publisher, RViz)."""
    root = _robot_element(text, "eURDF")
    for part in root.findall("body_part"):
        root.remove(part)
    return ET.tostring(root, encoding="unicode")


def robot_root(data: str | bytes, source: str) -> ET.Element:
    """The ``<robot>`` root element of URDF or eURDF text (bytes as read: XML's own encoding
    declaration applies), or ``invalid_eurdf`` naming ``source``. Parses only: bounds are the
    caller's."""
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise invalid(f"{source}: not well-formed XML ({exc})") from None
    if root.tag != "robot":
        raise invalid(f"{source}: root element must be <robot>, found <{root.tag}>")
    return root


def _robot_element(text: str, source: str) -> ET.Element:
    """The ``<robot>`` root of eURDF text, or ``invalid_eurdf`` naming ``source``.

    Bounded before anything walks the tree: no document type (entity declarations expand),
    at most :data:`MAX_ELEMENTS` elements nested at most :data:`MAX_NESTING` deep (the
    standard library's serialiser recurses once per level)."""
    if "<!DOCTYPE" in text or "<!ENTITY" in text:
        raise invalid(f"{source}: a document type declaration is not allowed in a URDF")
    root = robot_root(text, source)
    count = 0
    stack = [(root, 1)]
    while stack:
        el, depth = stack.pop()
        count += 1
        if depth > MAX_NESTING:
            raise invalid(f"{source}: XML elements nested more than {MAX_NESTING} deep "
                          f"(at <{el.tag:.40}>)")
        if count > MAX_ELEMENTS:
            raise invalid(f"{source}: more than {MAX_ELEMENTS} XML elements")
        stack.extend((child, depth + 1) for child in el)
    return root
