"""A score cast on every shipped body through its body vocabulary, and the parts measured by
kinesphere's forward kinematics (:mod:`kinesphere.pointing`, what ``play`` notates back with)
agreeing with yourdfpy's on the same eURDF (another reader, another kinematics)."""

from __future__ import annotations

import numpy as np
import pytest

from kinesphere.casting import cast
from kinesphere.eurdf import load_eurdf
from kinesphere.platforms.platform import load_platform
from kinesphere.pointing import Pointing
from kinesphere.vocabulary import vocabulary
from support.nested import MeasuredBody, SegmentEnds

ARMS = ("right elbow", "right wrist", "left elbow", "left wrist")


@pytest.mark.parametrize(("platform", "performs", "skipped", "turns"), [
    ("baxter", ARMS, {"head": "no head"}, False),
    ("nao", ("head", *ARMS), {}, True),
    ("youbot", ARMS[:2], {"head": "no head", "left elbow": "one arm: it performs the right "
                          "elbow column", "left wrist": "one arm: it performs the right wrist "
                          "column"}, True),
    ("packbot", ARMS[:2], {"head": "no head", "left elbow": "one arm: it performs the right "
                           "elbow column", "left wrist": "one arm: it performs the right "
                           "wrist column"}, True),
])
def test_every_body_performs_the_parts_it_has(platform: str, performs: tuple[str, ...],
                                              skipped: dict[str, str], turns: bool) -> None:
    p = load_platform(platform)
    c = cast(platform, vocabulary(p.eurdf), p.base.kind)
    assert sorted(r.column for r in c.roles) == sorted(performs)
    assert dict(c.skipped) == skipped
    assert c.turns is turns


@pytest.mark.parametrize("platform", ["baxter", "nao", "youbot", "packbot"])
def test_parts_point_as_yourdfpy_measures_them(platform: str) -> None:
    p = load_platform(platform)
    c = cast(platform, vocabulary(p.eurdf), p.base.kind)
    assert p.eurdf.path is not None
    pointing = Pointing(load_eurdf(p.eurdf.path.read_text(encoding="utf-8")))
    body = MeasuredBody(platform)
    rng = np.random.default_rng(3)
    names = list(p.eurdf.limits)
    for _ in range(20):
        joints = {n: float(rng.uniform(p.eurdf.limits[n].lower, p.eurdf.limits[n].upper))
                  for n in names}
        ours = pointing.directions([(r.start, r.end) for r in c.roles],
                                   {**p.neutral, **joints})
        body.pose(joints)
        for r, v in zip(c.roles, ours, strict=True):
            assert v is not None
            np.testing.assert_allclose(v, body.direction(SegmentEnds(r.start, r.end)), atol=1e-6)
