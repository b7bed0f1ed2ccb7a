"""The eURDF loader's checks: a broken description fails at load time with the element and
the problem named (see :mod:`kinesphere.eurdf`).

``check_urdf_elements`` and ``check_tree`` look at the URDF part, ``validate`` at the
``<body_part>`` labels against the kinematic tree.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import TYPE_CHECKING, Any

import yourdfpy

from kinesphere.errors import KinesphereError

if TYPE_CHECKING:
    from kinesphere.eurdf import BodyPart, JointLimit


def invalid(message: str) -> KinesphereError:
    return KinesphereError("invalid_eurdf", message)


def check_urdf_elements(root: ET.Element) -> None:
    links = [el.get("name") for el in root.findall("link")]
    if not links:
        raise invalid("<robot> has no <link>")
    for i, link_name in enumerate(links):
        if not link_name:
            raise invalid(f"<link> number {i + 1} has no name")
    seen: set[str] = set()
    for link_name in links:
        if link_name in seen:
            raise invalid(f"<link name={link_name!r}> appears twice")
        seen.add(str(link_name))
    for el in root.findall("joint"):
        jn = el.get("name")
        if not jn:
            raise invalid("a <joint> has no name")
        for tag in ("parent", "child"):
            ref = el.find(tag)
            target = ref.get("link") if ref is not None else None
            if not target:
                raise invalid(f"<joint name={jn!r}> has no <{tag} link=...>")
            if target not in seen:
                raise invalid(f"<joint name={jn!r}> {tag} link {target!r} does not exist")
        jtype = el.get("type")
        if jtype in ("revolute", "prismatic") and el.find("mimic") is None:
            lim = el.find("limit")
            if lim is None or lim.get("lower") is None or lim.get("upper") is None:
                raise invalid(f"<joint name={jn!r}> ({jtype}) needs <limit lower upper>")
            if float(lim.get("lower", "0")) > float(lim.get("upper", "0")):
                raise invalid(f"<joint name={jn!r}> has lower limit above upper limit")


def check_tree(urdf: yourdfpy.URDF) -> None:
    parent_of: dict[str, str] = {}
    for j in urdf.robot.joints:
        if j.child in parent_of:
            raise invalid(f"link {j.child!r} is the child of two joints; a URDF must be a tree")
        parent_of[j.child] = j.name
    roots = [str(link.name) for link in urdf.robot.links if link.name not in parent_of]
    if len(roots) != 1:
        raise invalid(f"a URDF has exactly one root link; found {roots or 'none (a cycle)'}")


def validate(
    urdf: yourdfpy.URDF,
    children: dict[str, list[tuple[str, str]]],
    limits: dict[str, JointLimit],
    parts: list[BodyPart],
) -> None:
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
        _check_limb(limb, distals, joint_map, children, limits)
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
    limits: dict[str, JointLimit],
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
    first = _subtree(root, children)
    # A location's further joints run in series below its first joint (a shoulder's pitch,
    # roll and yaw) or in parallel beside it (the fingers leaving a palm): the limb is
    # everything below any of them.
    subtree = list(first)
    for jn in distal.joints[1:]:
        child = joint_map[jn].child
        if child not in first:
            if joint_map[jn].parent in first:
                raise invalid(f"{distal.name}: joint {jn!r} is below {limb.name}'s root")
            subtree += [ln for ln in _subtree(child, children) if ln not in subtree]
    missing = sorted(set(subtree) - set(limb.links))
    extra = sorted(set(limb.links) - set(subtree))
    if missing or extra:
        what = f"misses {missing[:3]}" if missing else f"has links outside it: {extra[:3]}"
        raise invalid(
            f"<body_part name={limb.name!r}> must list exactly the subtree below joint "
            f"{distal.joints[0]!r} (root link {root!r}); it {what}"
        )
    if not any(joint_map[j].child in set(subtree) for j in limits):
        raise invalid(f"<body_part name={limb.name!r}> contains no actuated joint")


def _subtree(link: str, children: dict[str, list[tuple[str, str]]]) -> list[str]:
    out: list[str] = []
    stack = [link]
    while stack:
        cur = stack.pop()
        out.append(cur)
        stack.extend(c for _, c in children.get(cur, []))
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
