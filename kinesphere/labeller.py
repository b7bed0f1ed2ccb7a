"""Propose eURDF labels for a plain URDF, so a user can bring a new robot.

The proposal follows the paper's scheme: the root and everything welded to it is the core
``c_1``; every actuated joint leaving the core starts a chain ``i``; walking down a chain, each
new joint location (joints closer together than ``merge_distance`` form one location) opens
a deeper limb ``limb_ij`` rooted at ``distal_ij``. A chain's last location with nothing
actuated below it is the end effector and gets no label of its own. Chains are ordered like
the paper's humanoids: lateral chains first, higher before lower, right (y < 0) before left,
central chains (a head) last. The super-user edits the result as they see fit.
"""

from __future__ import annotations

import io
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yourdfpy

from kinesphere.errors import KinesphereError


def propose_eurdf(source: str | Path, merge_distance: float = 0.01) -> str:
    """Return eURDF text: the URDF unchanged plus proposed ``<body_part>`` elements."""
    path = Path(source)
    if not path.is_file():
        raise KinesphereError("invalid_eurdf", f"URDF file not found: {path}")
    text = path.read_text(encoding="utf-8")
    try:
        root_el = ET.fromstring(text)
        urdf = yourdfpy.URDF.load(io.StringIO(text), load_meshes=False, build_scene_graph=True)
    except Exception as exc:
        raise KinesphereError("invalid_eurdf", f"{path}: cannot read URDF ({exc})") from None
    for old in root_el.findall("body_part"):
        root_el.remove(old)
    for part in _proposal(urdf, merge_distance):
        root_el.append(part)
    ET.indent(root_el)
    return ET.tostring(root_el, encoding="unicode") + "\n"


def _actuated(j: yourdfpy.Joint) -> bool:
    return j.type in ("revolute", "prismatic", "continuous") and j.mimic is None


def _proposal(urdf: yourdfpy.URDF, merge_distance: float) -> list[ET.Element]:
    children: dict[str, list[yourdfpy.Joint]] = {}
    for j in urdf.robot.joints:
        children.setdefault(j.parent, []).append(j)
    root = str(urdf.base_link)
    core: list[str] = []
    chain_roots: list[yourdfpy.Joint] = []
    stack = [root]
    while stack:
        link = stack.pop()
        core.append(link)
        for j in children.get(link, []):
            if _actuated(j):
                chain_roots.append(j)
            else:
                stack.append(j.child)

    def anchor(j: yourdfpy.Joint) -> np.ndarray:
        return np.asarray(urdf.get_transform(j.child, root)[:3, 3])

    def subtree(link: str) -> list[str]:
        out, todo = [], [link]
        while todo:
            cur = todo.pop()
            out.append(cur)
            todo.extend(j.child for j in children.get(cur, []))
        return out

    def n_actuated(link: str) -> int:
        return sum(_actuated(j) for ln in subtree(link) for j in children.get(ln, []))

    def chain_key(j: yourdfpy.Joint) -> tuple[int, float, float]:
        x, y, z = anchor(j)
        return (1 if abs(y) < 0.02 else 0, -round(float(z), 2), float(y))

    parts: list[ET.Element] = []
    core_el = ET.Element("body_part", name="c_1", set="C", alias="core")
    for link in core:
        ET.SubElement(core_el, "link", name=link)
    parts.append(core_el)
    for i, first in enumerate(sorted(chain_roots, key=chain_key), start=1):
        if i > 9:
            break  # limb_<i><j> uses one digit per index; the super-user can relabel
        groups: list[list[yourdfpy.Joint]] = []
        cur: yourdfpy.Joint | None = first
        while cur is not None:
            if groups and np.linalg.norm(anchor(cur) - anchor(groups[-1][-1])) < merge_distance:
                groups[-1].append(cur)
            else:
                groups.append([cur])
            cur = _next_actuated(cur.child, children, n_actuated)
        if len(groups) > 1 and n_actuated(groups[-1][-1].child) == 0:
            groups.pop()  # the end effector: no label of its own
        for depth, group in enumerate(groups[:9], start=1):
            tag = f"{i}{depth}"
            limb = ET.Element("body_part", name=f"limb_{tag}", set="L", distal=f"distal_{tag}")
            for link in subtree(group[0].child):
                ET.SubElement(limb, "link", name=link)
            distal = ET.Element("body_part", name=f"distal_{tag}", set="J")
            for jj in group:
                ET.SubElement(distal, "joint", name=jj.name)
            parts += [limb, distal]
    return parts


def _next_actuated(
    link: str,
    children: dict[str, list[yourdfpy.Joint]],
    n_actuated: Callable[[str], int],
) -> yourdfpy.Joint | None:
    """The next actuated joint down the chain, following the richest branch."""
    frontier = [link]
    while frontier:
        found = [j for ln in frontier for j in children.get(ln, []) if _actuated(j)]
        if found:
            return max(found, key=lambda j: n_actuated(j.child))
        frontier = [j.child for ln in frontier for j in children.get(ln, [])]
    return None
