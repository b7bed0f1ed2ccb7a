"""The eURDF's ``<body_part>`` labels: core (C), limb (L) and distal joint location (J).

What a label is (:class:`BodyPart`), how one is read from its XML element, and the rules a
labelling must obey against the kinematic tree (names, subtrees, hierarchy, no unlabelled
link). :mod:`kinesphere.eurdf` reads the URDF part and calls :func:`validate`; a broken
labelling fails at load time with the element and the problem named.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Collection
from dataclasses import dataclass
from typing import Any, Literal, cast

from kinesphere.errors import KinesphereError
from kinesphere.urdf_tree import UrdfTree

PartSet = Literal["C", "L", "J"]
_NAME_RULES: dict[str, re.Pattern[str]] = {
    "C": re.compile(r"^c_(\d+)$"),
    "L": re.compile(r"^limb_(\d)(\d+)$"),
    "J": re.compile(r"^distal_(\d+)$"),
}


def invalid(message: str) -> KinesphereError:
    """The error of a broken eURDF."""
    return KinesphereError("invalid_eurdf", message)


@dataclass(frozen=True)
class BodyPart:
    """A label: core (C), limb (L) or distal joint location (J)."""

    name: str
    set: PartSet
    alias: str | None
    links: tuple[str, ...] = ()
    joints: tuple[str, ...] = ()
    distal: str | None = None
    tip: str | None = None

    @property
    def index(self) -> tuple[int, ...]:
        """Hierarchy index: ``limb_12`` -> (1, 2), ``distal_51`` -> (5, 1), ``c_1`` -> (1,)."""
        digits = self.name.split("_", 1)[1]
        return tuple(int(ch) for ch in digits) if self.set != "C" else (int(digits),)


def parse_part(el: ET.Element) -> BodyPart:
    name = el.get("name") or ""
    pset = el.get("set") or ""
    if not name:
        raise invalid("a <body_part> has no name")
    if pset not in _NAME_RULES:
        raise invalid(f"<body_part name={name!r}> has set={pset!r}; use C, L or J")
    if not _NAME_RULES[pset].match(name):
        pattern = {"C": "c_<i>", "L": "limb_<i><j>", "J": "distal_<i>[<j>]"}[pset]
        raise invalid(f"<body_part name={name!r}> in set {pset} must be named {pattern}")
    links = tuple(str(c.get("name")) for c in el.findall("link"))
    joints = tuple(str(c.get("name")) for c in el.findall("joint"))
    for child in el:
        if child.tag not in ("link", "joint") or not child.get("name"):
            raise invalid(f"<body_part name={name!r}> has a bad child <{child.tag}> (need name)")
    if pset == "J" and links:
        raise invalid(f"<body_part name={name!r}> (J) lists links; joint labels list <joint>s")
    if pset in "CL" and joints:
        raise invalid(f"<body_part name={name!r}> ({pset}) lists joints; it should list <link>s")
    tip = el.get("tip") or None
    if tip is not None and tip not in links:
        raise invalid(f"<body_part name={name!r}> tip={tip!r} is not one of its links")
    pset_typed = cast(PartSet, pset)
    return BodyPart(name, pset_typed, el.get("alias") or None, links, joints, el.get("distal"), tip)


def label_order(p: BodyPart) -> tuple[int, ...]:
    """Chain, then depth: limb_11, limb_12, limb_13, limb_21, ...; core joints first."""
    idx = p.index
    return idx if len(idx) > 1 else (0, idx[0])


def validate(
    urdf: UrdfTree,
    children: dict[str, list[tuple[str, str]]],
    actuated: Collection[str],
    parts: list[BodyPart],
) -> None:
    """Check every label of ``parts`` against the URDF tree (``children``: link -> (joint,
    child link)) and its ``actuated`` joints (P)."""
    link_names = set(urdf.link_map)
    joint_map: dict[str, Any] = dict(urdf.joint_map)
    names: dict[str, str] = {}
    for p in parts:
        for label in (p.name, p.alias):
            if label is None:
                continue
            if label in names:
                raise invalid(f"label {label!r} is used twice ({names[label]} and {p.name})")
            names[label] = p.name
        for ln in p.links:
            if ln not in link_names:
                raise invalid(
                    f"<body_part name={p.name!r}> names link {ln!r}, which does not exist"
                )
        for jn in p.joints:
            if jn not in joint_map:
                raise invalid(
                    f"<body_part name={p.name!r}> names joint {jn!r}, which does not exist"
                )
        if len(set(p.links)) != len(p.links) or len(set(p.joints)) != len(p.joints):
            raise invalid(f"<body_part name={p.name!r}> lists the same element twice")
    core = [p for p in parts if p.set == "C"]
    if not core:
        raise invalid('no core label: the set C needs at least one <body_part set="C">')
    distals = {p.name: p for p in parts if p.set == "J"}
    _check_distals(distals, joint_map)
    limbs = {p.name: p for p in parts if p.set == "L"}
    for limb in limbs.values():
        _check_limb(limb, distals, joint_map, children, actuated)
    _check_hierarchy(limbs)
    in_limbs = {ln for p in limbs.values() for ln in p.links}
    in_core = {ln for p in core for ln in p.links}
    overlap = sorted(in_core & in_limbs)
    if overlap:
        raise invalid(f"link {overlap[0]!r} is labelled both core and limb")
    unlabelled = [ln for ln in urdf.link_map if ln not in in_core | in_limbs]
    if unlabelled:
        raise invalid(f"link {unlabelled[0]!r} has no core or limb label")
    for d in distals.values():
        if len(d.index) > 1 and f"limb_{d.name.split('_', 1)[1]}" not in limbs:
            raise invalid(f"<body_part name={d.name!r}> has no matching limb label")


def _check_distals(distals: dict[str, BodyPart], joint_map: dict[str, Any]) -> None:
    owner: dict[str, str] = {}
    for d in distals.values():
        if not d.joints:
            raise invalid(f"<body_part name={d.name!r}> (J) lists no <joint>")
        for jn in d.joints:
            if jn in owner:
                raise invalid(f"joint {jn!r} is labelled by both {owner[jn]} and {d.name}")
            owner[jn] = d.name
            if joint_map[jn].type == "fixed":
                raise invalid(f"<body_part name={d.name!r}> names fixed joint {jn!r}")


def _check_limb(
    limb: BodyPart,
    distals: dict[str, BodyPart],
    joint_map: dict[str, Any],
    children: dict[str, list[tuple[str, str]]],
    actuated: Collection[str],
) -> None:
    expected_distal = "distal_" + limb.name.split("_", 1)[1]
    if limb.distal is None:
        raise invalid(f"<body_part name={limb.name!r}> needs distal={expected_distal!r}")
    if limb.distal != expected_distal:
        raise invalid(
            f"<body_part name={limb.name!r}> has distal={limb.distal!r}; "
            f"indices must match: {expected_distal}"
        )
    if limb.distal not in distals:
        raise invalid(f"<body_part name={limb.name!r}> refers to missing {limb.distal!r}")
    distal = distals[limb.distal]
    root = joint_map[distal.joints[0]].child
    first = subtree(root, children)
    # A location's further joints run in series below its first joint (a shoulder's pitch,
    # roll and yaw) or in parallel beside it (the fingers leaving a palm): the limb is
    # everything below any of them.
    below = list(first)
    for jn in distal.joints[1:]:
        child = joint_map[jn].child
        if child not in first:
            if joint_map[jn].parent in first:
                raise invalid(f"{distal.name}: joint {jn!r} is below {limb.name}'s root")
            below += [ln for ln in subtree(child, children) if ln not in below]
    missing = sorted(set(below) - set(limb.links))
    extra = sorted(set(limb.links) - set(below))
    if missing or extra:
        what = f"misses {missing[:3]}" if missing else f"has links outside it: {extra[:3]}"
        raise invalid(
            f"<body_part name={limb.name!r}> must list exactly the subtree below joint "
            f"{distal.joints[0]!r} (root link {root!r}); it {what}"
        )
    if not any(joint_map[j].child in set(below) for j in actuated):
        raise invalid(f"<body_part name={limb.name!r}> contains no actuated joint")


def subtree(link: str, children: dict[str, list[tuple[str, str]]]) -> list[str]:
    """``link`` and every link below it in the tree ``children`` (link -> (joint, child
    link) in document order), depth first in document order."""
    out: list[str] = []
    stack = [link]
    while stack:
        cur = stack.pop()
        out.append(cur)
        stack.extend(c for _, c in reversed(children.get(cur, [])))
    return out


def _check_hierarchy(limbs: dict[str, BodyPart]) -> None:
    by_index = {p.index: p for p in limbs.values()}
    for (chain, depth), limb in sorted(by_index.items()):
        if depth > 1:
            parent = by_index.get((chain, depth - 1))
            if parent is None:
                raise invalid(f"{limb.name} has no parent limb limb_{chain}{depth - 1}")
            if not set(limb.links) < set(parent.links):
                raise invalid(f"{limb.name} must be a strict subtree of {parent.name}")
    firsts = [p for (_, depth), p in by_index.items() if depth == 1]
    for i, a in enumerate(firsts):
        for b in firsts[i + 1 :]:
            if set(a.links) & set(b.links):
                raise invalid(
                    f"{a.name} and {b.name} overlap; first-level limbs are disjoint chains"
                )
