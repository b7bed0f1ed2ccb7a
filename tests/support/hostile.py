"""Hostile bodies for the hardening tests: eURDF text a forged databank answer could carry.

Not a test module. Each body is a labelled robot that a URDF library would load, except for
the one thing it breaks (a number that is not one, a shape with the wrong arity, a chain
too long, XML nested too deep), so a test shows that exact flaw is what gets it refused.
"""

from __future__ import annotations

import hashlib

from kinesphere.protocol import BodyModel

SCRIPT = '<iframe srcdoc="<script>top.document.title=\'OWNED\'</script>">'
"""61 characters that ran script in the operator's page through the side panel's Markdown."""
IMG = '<img src=x onerror="top.document.title=\'OWNED\'">'
"""The same through an image's error handler (no iframe needed)."""


def arm(links: int, *, geometry: str = '<box size="0.05 0.05 0.2"/>', limit: str = "",
        name: str = "chain") -> str:
    """A labelled serial arm of ``links`` links below a box core, each with ``geometry``."""
    lim = limit or 'lower="-1" upper="1" velocity="1" effort="1"'
    out = [f'<robot name="{name}">',
           '<link name="base"><visual><geometry><box size="0.3 0.3 0.2"/></geometry>'
           '</visual></link>']
    for i in range(links):
        out.append(f'<link name="l{i}"><visual><origin xyz="0 0 0.1"/><geometry>{geometry}'
                   '</geometry></visual></link>')
    for i in range(links):
        parent = "base" if i == 0 else f"l{i - 1}"
        out.append(f'<joint name="j{i}" type="revolute"><parent link="{parent}"/>'
                   f'<child link="l{i}"/><origin xyz="0 0 0.2"/><axis xyz="0 1 0"/>'
                   f'<limit {lim}/></joint>')
    out.append('<body_part name="c_1" set="C"><link name="base"/></body_part>')
    members = "".join(f'<link name="l{i}"/>' for i in range(links))
    out.append(f'<body_part name="limb_11" set="L" alias="arm" distal="distal_11">{members}'
               '</body_part>')
    out.append('<body_part name="distal_11" set="J"><joint name="j0"/></body_part>')
    out.append("</robot>")
    return "\n".join(out)


def nested(depth: int) -> str:
    """A small arm whose first link carries XML elements nested ``depth`` deep (no URDF
    meaning: a parser or serialiser that recurses per level runs out of stack)."""
    text = arm(2)
    junk = "<x>" * depth + "</x>" * depth
    return text.replace('<link name="l0">', f'<link name="l0">{junk}', 1)


def model(eurdf: str, platform: str = "hostile") -> BodyModel:
    """``eurdf`` as the databank's body answer."""
    return BodyModel(platform=platform, eurdf=eurdf, base_kind="fixed", neutral={},
                     version=hashlib.sha256(eurdf.encode()).hexdigest())


BROKEN_NUMBERS = {
    "limit lower abc": arm(3, limit='lower="abc" upper="1" velocity="1" effort="1"'),
    "limit upper nan": arm(3, limit='lower="-1" upper="nan" velocity="1" effort="1"'),
    "cylinder radius nan": arm(3, geometry='<cylinder radius="nan" length="0.2"/>'),
    "box of two numbers": arm(3, geometry='<box size="1 1"/>'),
    "sphere radius inf": arm(3, geometry='<sphere radius="inf"/>'),
    "box negative": arm(3, geometry='<box size="1 -1 1"/>'),
    "huge box": arm(3, geometry='<box size="1e300 1 1"/>'),
    "origin nan": arm(3).replace('<origin xyz="0 0 0.2"/>', '<origin xyz="0 nan 0.2"/>', 1),
    "rpy of two": arm(3).replace('<origin xyz="0 0 0.2"/>', '<origin xyz="0 0 0.2" rpy="0 1"/>',
                                 1),
    "axis zero": arm(3).replace('<axis xyz="0 1 0"/>', '<axis xyz="0 0 0"/>', 1),
    "mesh scale nan": arm(3, geometry='<mesh filename="m.stl" scale="1 nan 1"/>'),
}
"""Bodies with one malformed number or shape each: every one must be refused by name."""
