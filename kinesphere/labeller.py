"""Propose eURDF labels for a plain URDF, so a user can bring a new robot.

The proposal follows the paper's scheme (its Fig. 3):

* **core** ``C``: the root and everything welded to it is ``c_1``. An actuated joint on the way
  from the root to a link where two or more limbs branch off (a torso lift, a waist, a spine)
  is a *core joint*: its location is ``distal_k`` and the links beyond it are ``c_{k+1}``.
  Drive wheels, casters and rotors hanging off the core stay in the core's links.
* **chains**: every other actuated joint leaving the core starts a chain ``i`` (an arm, a leg,
  a head). Walking down a chain, each new joint location (joints closer together than
  ``merge_distance`` form one location) opens a deeper limb ``limb_ij`` rooted at
  ``distal_ij``. A chain's last location with nothing actuated below it is the end effector
  and gets no label of its own.
* **hands**: a chain stops where it branches into fingers or reaches a gripper joint; the
  fingers are one limb of their own, rooted at a location that lists every finger joint
  leaving the palm.

Chains are numbered like the paper's humanoids: lateral chains first, higher before lower,
front before back, right (y < 0) before left, central chains (a head) last. Aliases come from
the URDF's own names (:mod:`kinesphere.labeller_names`). It proposes; the super-user edits the
result as they see fit and ``kinesphere describe FILE`` checks it.
"""

from __future__ import annotations

import io
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yourdfpy

from kinesphere.cliargs import MERGE_DISTANCE_M
from kinesphere.errors import KinesphereError
from kinesphere.eurdf import ACTUATED_TYPES
from kinesphere.labeller_names import (
    Namer,
    has_word,
    is_core_name,
    is_drive_name,
    is_finger_name,
    is_limb_name,
    is_steer_name,
)
from kinesphere.urdfmend import Mends, check, mend, parse, read_bytes

HAND_FRACTION = 0.15  # a branch shorter than this share of the robot is a hand's, not a limb
MAX_INDEX = 9  # limb_<i><j> and distal_<k> use one digit per index


def read_urdf(source: str | Path, mends: Mends | None = None) -> tuple[ET.Element, yourdfpy.URDF]:
    """Read a third-party URDF file within bounds, checked and mended
    (:mod:`kinesphere.urdfmend`; the mends are added to ``mends``), into XML and yourdfpy.

    A ``<robot>`` without a name gets the file's stem, as ROS tools assume.
    """
    path = Path(source)
    said = mends if mends is not None else Mends()
    root = parse(read_bytes(path), str(path), said)
    if not root.get("name"):
        root.set("name", path.stem)
    try:
        check(root)
        mend(root, said)
    except KinesphereError as exc:
        raise KinesphereError(exc.code, f"{path}: cannot read URDF ({exc.message})") from None
    try:
        urdf = yourdfpy.URDF.load(
            io.BytesIO(ET.tostring(root)), load_meshes=False, build_scene_graph=False,
            build_collision_scene_graph=False,
        )
    except Exception as exc:  # yourdfpy raises assorted types
        raise KinesphereError("invalid_eurdf", f"{path}: cannot read URDF ({exc})") from None
    return root, urdf


def xml_comment(text: str) -> ET.Element:  # an ET.Comment is an Element with a callable tag
    """A comment whose text cannot end it early (``--`` is not allowed inside one)."""
    clean = "".join(c if c.isprintable() else " " for c in text)
    while "--" in clean:
        clean = clean.replace("--", "- -")
    return ET.Comment(f" {clean.rstrip('-')} ")  # type: ignore[return-value]


def propose_eurdf(source: str | Path, merge_distance: float = MERGE_DISTANCE_M) -> str:
    """Return eURDF text: the URDF (mended, each mend in a comment) plus proposed
    ``<body_part>`` elements."""
    mends = Mends()
    root_el, urdf = read_urdf(source, mends)
    for old in root_el.findall("body_part"):
        root_el.remove(old)
    for k, line in enumerate(mends.lines):
        root_el.insert(k, xml_comment(f"kinesphere: {line}"))
    for part in propose(urdf, merge_distance).elements():
        root_el.append(part)
    ET.indent(root_el)
    return ET.tostring(root_el, encoding="unicode") + "\n"


def actuated(j: yourdfpy.Joint) -> bool:
    return j.type in ACTUATED_TYPES and j.mimic is None


@dataclass
class Location:
    """One joint location: its label, alias and joints (first joint = the origin)."""

    label: str
    alias: str | None
    joints: list[yourdfpy.Joint]


@dataclass
class Limb:
    """One limb label: the links below its location, and its tip when a hand hangs below it
    (the palm or flange: the hand's joints are then no joints of this limb)."""

    label: str
    alias: str | None
    location: Location
    links: list[str]
    tip: str | None = None


@dataclass
class Proposal:
    """The labels the labeller proposes: core parts and their joints, chains of limbs."""

    core: list[tuple[str, str | None, list[str]]] = field(default_factory=list)
    core_joints: list[Location] = field(default_factory=list)
    limbs: list[Limb] = field(default_factory=list)
    hands: list[str] = field(default_factory=list)  # limb labels that are hands or grippers
    kinds: dict[str, str] = field(default_factory=dict)  # first-level limb -> arm, leg, head

    def elements(self) -> list[ET.Element]:
        out: list[ET.Element] = []
        for name, alias, links in self.core:
            el = _part(name, "C", alias)
            for ln in links:
                ET.SubElement(el, "link", name=ln)
            out.append(el)
        for loc in self.core_joints:
            out.append(_location(loc))
        for limb in self.limbs:
            extra = {"distal": limb.location.label, **({"tip": limb.tip} if limb.tip else {})}
            el = _part(limb.label, "L", limb.alias, **extra)
            for ln in limb.links:
                ET.SubElement(el, "link", name=ln)
            out += [el, _location(limb.location)]
        return out


def _part(name: str, pset: str, alias: str | None, **extra: str) -> ET.Element:
    attrs = {"name": name, "set": pset, **({"alias": alias} if alias else {}), **extra}
    return ET.Element("body_part", attrs)


def _location(loc: Location) -> ET.Element:
    el = _part(loc.label, "J", loc.alias)
    for j in loc.joints:
        ET.SubElement(el, "joint", name=j.name)
    return el


def link_frames(
    urdf: yourdfpy.URDF, root: str, children: dict[str, list[yourdfpy.Joint]] | None = None
) -> tuple[dict[str, np.ndarray], list[str]]:
    """Every link's frame in the root's at the zero pose, and the links root first."""
    if children is None:
        children = {}
        for j in urdf.robot.joints:
            children.setdefault(j.parent, []).append(j)
    frames = {root: np.eye(4)}
    order = [root]
    for link in order:
        for j in children.get(link, []):
            origin = j.origin if j.origin is not None else np.eye(4)
            frames[j.child] = frames[link] @ origin
            order.append(j.child)
    return frames, order


class _Tree:
    """The kinematic tree at the zero pose, with the questions the labeller asks of it.

    Every answer about a subtree is computed once (the labeller asks them for every link), so
    labelling costs time in proportion to links times depth, not a power of the link count.
    """

    def __init__(self, urdf: yourdfpy.URDF) -> None:
        self.urdf = urdf
        self.children: dict[str, list[yourdfpy.Joint]] = {}
        parents = set()
        for j in urdf.robot.joints:
            self.children.setdefault(j.parent, []).append(j)
            parents.add(j.child)
        self.root = next(str(ln.name) for ln in urdf.robot.links if ln.name not in parents)
        self.frame, order = link_frames(urdf, self.root, self.children)
        self.order = order
        self.pos = {ln: f[:3, 3] for ln, f in self.frame.items()}
        pts = np.array(list(self.pos.values()))
        self.size = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0))) or 1.0
        self.mimicked = {j.mimic.joint for j in urdf.robot.joints if j.mimic is not None}
        self._subtree: dict[str, list[str]] = {}
        self._actuated: dict[str, list[yourdfpy.Joint]] = {}
        for link in reversed(order):  # leaves first: each answer reuses its children's
            below = self.children.get(link, [])
            self._subtree[link] = [link, *(x for j in below for x in self._subtree[j.child])]
            self._actuated[link] = [
                x for j in below for x in ([j] if actuated(j) else []) + self._actuated[j.child]
            ]

    def subtree(self, link: str) -> list[str]:
        return self._subtree[link]

    def actuated_in(self, j: yourdfpy.Joint) -> list[yourdfpy.Joint]:
        """The actuated joints of a branch: ``j`` itself and everything below it."""
        return ([j] if actuated(j) else []) + self._actuated[j.child]

    def branches(self, link: str) -> list[yourdfpy.Joint]:
        """Child joints of ``link`` whose branch holds an actuated joint."""
        return [j for j in self.children.get(link, []) if self.actuated_in(j)]

    def extent(self, j: yourdfpy.Joint) -> float:
        base = self.pos[j.parent]
        return max(float(np.linalg.norm(self.pos[ln] - base)) for ln in self.subtree(j.child))

    def first_actuated(self, link: str) -> list[yourdfpy.Joint]:
        """The first actuated joint on each branch below ``link`` (through fixed and mimic)."""
        out: list[yourdfpy.Joint] = []
        for j in self.children.get(link, []):
            out += [j] if actuated(j) else self.first_actuated(j.child)
        return out

    def anchor(self, j: yourdfpy.Joint) -> np.ndarray:
        return self.pos[j.child]

    def vertical(self, j: yourdfpy.Joint) -> bool:
        """The joint turns about the root's z axis (a steering hinge, a caster's swivel)."""
        axis = np.asarray(j.axis if j.axis is not None else [1.0, 0.0, 0.0], dtype=float)
        world = self.frame[j.child][:3, :3] @ (axis / (np.linalg.norm(axis) or 1.0))
        return abs(float(world[2])) > 0.95

    def is_drive(self, j: yourdfpy.Joint) -> bool:
        """A wheel, caster, suspension or rotor branch, steered or not: part of the core,
        like the paper's youBot wheels (a racecar's steering hinge carries its wheel)."""
        joints = self.actuated_in(j)
        if any(is_limb_name(x.name) for x in joints):
            return False
        if all(is_drive_name(x.name) for x in joints):
            return True
        ends = [x for x in joints if not self._actuated[x.child]]
        wheels = [x for x in ends if is_drive_name(x.name) or x.type == "continuous"]
        steering = [x for x in joints if x not in ends]
        if ends and len(wheels) == len(ends) and any(is_drive_name(x.name) for x in joints):
            return all(is_steer_name(x.name) or self.vertical(x) for x in steering)
        return len(joints) == 1 and joints[0].type == "continuous"

    def is_limb_branch(self, j: yourdfpy.Joint) -> bool:
        """A branch that is an arm, leg or head rather than a finger or a sensor mount."""
        names = [x.name for x in self.actuated_in(j)]
        if is_finger_name(names[0]):
            return False
        return any(is_limb_name(n) for n in names) or self.extent(j) >= HAND_FRACTION * self.size

    def gripper_joint(self, j: yourdfpy.Joint) -> bool:
        """A single joint that closes a gripper: named so, or driving mimic fingers."""
        return is_finger_name(j.name) or (
            j.name in self.mimicked and not self.first_actuated(j.child)
        )

    def lateral(self, j: yourdfpy.Joint) -> float | None:
        """Where a chain's joints sit across the body (their mean y), or None when they all
        sit on the middle line: a head turning there is central, whatever it carries aside
        (R2D2's eye box)."""
        ys = [float(self.anchor(x)[1]) for x in self.actuated_in(j)]
        if max(abs(y) for y in ys) <= max(0.02, 0.03 * self.size):
            return None
        mean = float(np.mean(ys))
        return mean if mean else None

    def palm(self, hand: list[yourdfpy.Joint]) -> str:
        """The link a hand's joints leave from (their deepest common ancestor): the tip of the
        arm it ends."""
        paths = [self._path(j.parent) for j in hand]
        common = paths[0]
        for p in paths[1:]:
            common = [a for a, b in zip(common, p, strict=False) if a == b]
        return common[-1]

    def _path(self, link: str) -> list[str]:
        parent = {j.child: j.parent for j in self.urdf.robot.joints}
        out = [link]
        while out[-1] in parent:
            out.append(parent[out[-1]])
        return out[::-1]


def propose(urdf: yourdfpy.URDF, merge_distance: float = MERGE_DISTANCE_M) -> Proposal:
    """The labels for a URDF: core parts and joints, then chains in the paper's order."""
    tree = _Tree(urdf)
    core_joints = _core_joints(tree)
    namer = Namer()
    proposal = Proposal()
    parts: list[list[str]] = [[]]
    part_of: dict[str, int] = {tree.root: 0}
    chain_roots: list[tuple[yourdfpy.Joint, int]] = []
    todo = [tree.root]
    while todo:
        link = todo.pop(0)
        k = part_of[link]
        parts[k].append(link)
        for j in tree.children.get(link, []):
            if j.name in core_joints and len(proposal.core_joints) < MAX_INDEX:
                prev = proposal.core_joints[-1] if proposal.core_joints else None
                if (
                    prev is not None
                    and prev.joints[-1].child == j.parent
                    and _close(tree, prev.joints[-1], j, merge_distance)
                ):
                    prev.joints.append(j)  # same location: the link between joins the part
                    part_of[j.child] = k
                else:
                    n = len(proposal.core_joints) + 1
                    proposal.core_joints.append(
                        Location(f"distal_{n}", namer.core_joint(j.name), [j])
                    )
                    parts.append([])
                    part_of[j.child] = len(parts) - 1
                todo.append(j.child)
            elif actuated(j) and not tree.is_drive(j):
                chain_roots.append((j, k))
            else:
                part_of[j.child] = k
                todo.append(j.child)
    chains = sorted(chain_roots, key=lambda c: _chain_key(tree, c[0]))
    fore = _fore_by_geometry(tree, [c[0] for c in chains])
    for i, (first, k) in enumerate(chains, start=1):
        if i > MAX_INDEX:
            parts[k] += tree.subtree(first.child)  # the super-user may relabel these
            continue
        _label_chain(tree, proposal, namer, i, first, merge_distance, len(chains) == 1,
                     fore.get(first.name))
    for k, links in enumerate(parts, start=1):
        alias = "core" if k == 1 else namer.core_part(links)
        proposal.core.append((f"c_{k}", alias, links))
    return proposal


def _close(tree: _Tree, a: yourdfpy.Joint, b: yourdfpy.Joint, merge_distance: float) -> bool:
    return float(np.linalg.norm(tree.anchor(a) - tree.anchor(b))) < merge_distance


def _core_joints(tree: _Tree) -> set[str]:
    """Actuated joints between the root and every link where two or more limbs branch off,
    plus a torso/waist/spine chain leaving the root core, when the tree agrees: it is the one
    limb-bearing branch there (four legs leaving a torso are legs, whatever their names say)."""
    parent_joint = {j.child: j for j in tree.urdf.robot.joints}

    def path_to(link: str) -> list[yourdfpy.Joint]:
        out = []
        while link in parent_joint:
            j = parent_joint[link]
            out.append(j)
            link = j.parent
        return out

    core: set[str] = set()
    for link in tree.order:
        limbs = [j for j in tree.branches(link) if tree.is_limb_branch(j)]
        if len(limbs) >= 2:
            core |= {j.name for j in path_to(link) if actuated(j)}
    frontier = [tree.root]
    seen: set[str] = set()
    while frontier:
        link = frontier.pop()
        if link in seen:
            continue
        seen.add(link)
        bearing = [j for j in tree.branches(link)
                   if not tree.is_drive(j) and tree.is_limb_branch(j)]
        for j in tree.children.get(link, []):
            named = is_core_name(j.name) and bearing == [j]
            if not actuated(j) or j.name in core or named:
                if actuated(j):
                    core.add(j.name)
                frontier.append(j.child)
    return core


def _chain_key(tree: _Tree, j: yourdfpy.Joint) -> tuple[int, float, float, int]:
    """Lateral before central, higher before lower, front before back, right before left."""
    side = Namer.side_of([j.name, *tree.subtree(j.child)])
    lateral = tree.lateral(j) is not None or side is not None
    x, _, z = tree.anchor(j)
    rank = {"right": 0, "left": 1}.get(side or "", 2)
    return (0 if lateral else 1, -round(float(z), 2), -round(float(x), 2), rank)


def _fore_by_geometry(tree: _Tree, firsts: list[yourdfpy.Joint]) -> dict[str, str]:
    """Front or hind for the chains of a robot with four or more lateral chains at one
    height (a quadruped whose names say nothing): by where each hangs along x."""
    lateral = [j for j in firsts if tree.lateral(j) is not None]
    if len(lateral) < 4:
        return {}
    xs = np.array([float(tree.anchor(j)[0]) for j in lateral])
    mid = float(np.median(xs))
    gap = 0.05 * tree.size
    return {j.name: "front" if x > mid + gap else "hind"
            for j, x in zip(lateral, xs, strict=True) if abs(x - mid) > gap}


def _label_chain(
    tree: _Tree,
    proposal: Proposal,
    namer: Namer,
    i: int,
    first: yourdfpy.Joint,
    merge_distance: float,
    only: bool,
    fore: str | None,
) -> None:
    """Walk one chain from the core: its joint locations, then its hand if it has one."""
    groups: list[list[yourdfpy.Joint]] = []
    hand: list[yourdfpy.Joint] = []
    cur: yourdfpy.Joint | None = first
    finger = is_finger_name(first.name)  # a chain that is a finger (a robot finger) goes on
    while cur is not None:
        if groups and _close(tree, groups[-1][-1], cur, merge_distance):
            groups[-1].append(cur)
        else:
            groups.append([cur])
        nxt = tree.first_actuated(cur.child)
        if len(nxt) > 1 or (len(nxt) == 1 and not finger and tree.gripper_joint(nxt[0])):
            hand = nxt
            break
        cur = nxt[0] if nxt else None
    if not hand and len(groups) > 1 and not tree.actuated_in(groups[-1][-1])[1:]:
        groups.pop()  # the end effector: no label of its own
    tip = None
    if hand:
        tip = tree.palm(hand)
        parents = {j.parent for j in hand}
        hand += [  # a gripper's mimic fingers belong to its location
            j
            for p in parents
            for j in tree.children.get(p, [])
            if j.mimic is not None and j.type in ACTUATED_TYPES
        ]
    chain_names = [j.name for g in groups for j in g] + tree.subtree(first.child)
    kind = namer.chain(chain_names, tree.lateral(first), len(groups), only, fore)
    if kind.kind is not None:
        proposal.kinds[f"limb_{i}1"] = kind.kind
    for depth, group in enumerate(groups[: MAX_INDEX - (1 if hand else 0)], start=1):
        tag = f"{i}{depth}"
        words = [j.name for j in group]
        loc = Location(f"distal_{tag}", namer.location(kind, depth, words), group)
        links = tree.subtree(group[0].child)
        proposal.limbs.append(Limb(f"limb_{tag}", namer.limb(kind, depth, words), loc, links,
                                   tip))
    if hand:
        tag = f"{i}{min(len(groups), MAX_INDEX - 1) + 1}"
        gripper = len(tree.first_actuated(hand[0].parent)) <= 2 or any(
            has_word(j.name, "gripper") for j in hand
        )
        loc = Location(f"distal_{tag}", None, hand)
        links = [ln for j in hand for ln in tree.subtree(j.child)]
        proposal.limbs.append(Limb(f"limb_{tag}", namer.hand(kind, gripper), loc, links))
        proposal.hands.append(f"limb_{tag}")
