"""Fuzzed bodies on the view's body path: every one drawn or refused by name, never a crash,
each parsed once, memory bounded.

The shipped bodies (the databank's answers for every platform) are mutated as a forged
databank answer could be: a number made NaN, infinite, huge, text or of the wrong arity, an
element dropped or doubled (a link twice, a second parent), a chain lengthened past the
bound, junk nested deep, the text cut short, mesh names pointing anywhere. Each goes through
the view's own path (:class:`~kinesphere.clients.view.resolve.Bodies`: digest, check, build
once). ``make soak`` runs it ``KINESPHERE_SOAK_SCALE`` times larger and prints its ``SOAK``
line (bodies, outcomes, slowest build, memory).
"""

from __future__ import annotations

import os
import random
import re
import time
import xml.etree.ElementTree as ET

from kinesphere.clients.view.resolve import MAX_BODIES, Bodies
from kinesphere.errors import KinesphereError
from kinesphere.platforms.platform import load_platform, platform_names
from kinesphere.services.databank.body import body_model
from support.hostile import model
from support.soak import SCALE, FloodTally, mib, rss

BODIES = 150 * SCALE
NUMBERS = ("nan", "inf", "-inf", "1e308", "-1e308", "abc", "", "1 2", "1 2 3 4", "0x10",
           "-0", "1e-320", "9" * 400)
NAMES = ("/etc/passwd", "../../x.stl", "file:///etc/shadow", "package://p/m.stl", "meshes/a.stl",
         "x" * 300)


def _mutate(text: str, rng: random.Random) -> str:
    kind = rng.randrange(7)
    if kind == 6:  # cut short (no longer XML, or missing its end)
        return text[: rng.randrange(len(text))]
    root = ET.fromstring(text)
    elements = list(root.iter())
    el = rng.choice(elements)
    if kind == 0:  # a number made anything
        numeric = [(e, a) for e in elements for a, v in e.attrib.items()
                   if re.fullmatch(r"[-+0-9.eE ]+", v)]
        e, a = rng.choice(numeric)
        e.set(a, rng.choice(NUMBERS))
    elif kind == 1 and el is not root:  # an element dropped
        for parent in root.iter():
            if el in list(parent):
                parent.remove(el)
                break
    elif kind == 2:  # an element doubled (a link twice, a joint giving a child two parents)
        twin = rng.choice([e for e in root if e.tag in ("link", "joint", "body_part")])
        root.append(ET.fromstring(ET.tostring(twin)))
    elif kind == 3:  # a chain lengthened
        links = root.findall("link")
        last = rng.choice(links).get("name")
        assert last is not None, "the platform's links are named"
        for i in range(rng.choice((10, 70, 600))):
            ET.SubElement(root, "link", name=f"fz{i}")
            j = ET.SubElement(root, "joint", name=f"fzj{i}", type="fixed")
            ET.SubElement(j, "parent", link=last if i == 0 else f"fz{i - 1}")
            ET.SubElement(j, "child", link=f"fz{i}")
    elif kind == 4:  # junk nested deep (as text: the standard serialiser would recurse)
        depth = rng.choice((5, 40, 3000))
        at = text.index(">", text.index("<link ")) + 1
        return text[:at] + "<x>" * depth + "</x>" * depth + text[at:]
    else:  # a visual naming a mesh anywhere
        link = rng.choice(root.findall("link"))
        visual = ET.SubElement(link, "visual")
        ET.SubElement(ET.SubElement(visual, "geometry"), "mesh", filename=rng.choice(NAMES))
    return ET.tostring(root, encoding="unicode")


def test_fuzzed_bodies_are_drawn_or_refused_by_name() -> None:
    shipped = [body_model(load_platform(name)).eurdf for name in platform_names()]
    rng = random.Random(29)
    bodies = Bodies()
    tally = FloodTally("view body fuzz")
    slowest = 0.0
    before = rss(os.getpid())
    half = before
    for i in range(BODIES):
        text = _mutate(rng.choice(shipped), rng)
        tally.sent += 1
        t0 = time.perf_counter()
        try:
            for name in (f"fz-{i}", f"fz-{i}-again"):  # the same body twice: parsed once
                bodies.body(model(text, platform=name))
            tally.add("drawn")
        except KinesphereError as exc:
            tally.add(exc.code)
        slowest = max(slowest, time.perf_counter() - t0)
        if i == BODIES // 2:
            half = rss(os.getpid())
    after = rss(os.getpid())
    tally.extra.update({"parsed": bodies.built, "slowest build": f"{slowest:.2f} s",
                        "RSS": f"{mib(before)} -> {mib(half)} (half) -> {mib(after)}"})
    tally.report()
    assert set(tally.codes) <= {"drawn", "invalid_eurdf"}, tally.codes
    assert tally.codes["invalid_eurdf"] > BODIES // 4 and tally.codes["drawn"] > 0
    assert bodies.built <= BODIES  # twice each, parsed once
    assert len(bodies._known) <= MAX_BODIES
    assert after - half < 64 * 1024 * 1024, "the second half grew the view's memory"
