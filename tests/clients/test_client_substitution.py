"""The gamepad's substitution against the shipped catalogues of every platform.

Each platform's catalogue is read from its real databank (the same ``Catalogue`` the databank
serves), and the stick goes through the real mapping: 8 headings x 3 levels on every limb the
right stick can select. What the operator pushes towards the front (back) stays in front
(behind) whenever the limb has anything there, and a lateral push is never served from behind.
"""

from __future__ import annotations

import math

import pytest

from kinesphere.clients.gamepad import limbs
from kinesphere.clients.gamepad.mapping import MapperState, map_controls
from kinesphere.clients.gamepad.state import ControllerState
from kinesphere.clients.gamepad.sticks import Tuning
from kinesphere.errors import KinesphereError
from kinesphere.laban import RING, Direction, Level
from kinesphere.platforms.platform import platform_names
from kinesphere.protocol import Catalogue
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.substitution import MAX_ANGLE_DEG, angle_between, forward_sign

ECLS = {p: Ecl.open(p) for p in platform_names()}
CATALOGUES = {p: ecl.catalogue() for p, ecl in ECLS.items()}
TRIGGERS = {Level.LOW: (1.0, 0.0), Level.MIDDLE: (0.0, 0.0), Level.HIGH: (0.0, 1.0)}
"""The (left, right) trigger that asks for each level."""


def every_limb() -> list[tuple[str, Catalogue, str, str]]:
    """Each platform's (limb, origin) pairs its catalogue lists, named for the test ids."""
    return [
        (f"{p}/{limb}/{origin}", cat, limb, origin)
        for p, cat in CATALOGUES.items()
        for limb, origin in limbs.pairs_of([cat])
        if any((e.limb, e.origin) == (limb, origin) for e in cat.limbs)
    ]


LIMBS = every_limb()


def pushed(heading_deg: float, level: Level) -> Direction:
    """What the mapping makes of the right stick at the rim towards ``heading_deg`` (0 =
    forward, 90 = left) with the trigger of ``level``."""
    a = math.radians(heading_deg)
    lt, rt = TRIGGERS[level]
    cs = ControllerState(rx=-math.sin(a), ry=-math.cos(a), lt=lt, rt=rt)
    return map_controls(cs, MapperState(), 0.0, Tuning())[0].direction


def test_every_articulated_platform_is_covered() -> None:
    assert {c.platform for _, c, _, _ in LIMBS} == {"baxter", "nao", "packbot", "youbot"}
    every = {(c.platform, e.limb, e.origin) for c in CATALOGUES.values() for e in c.limbs
             if e.limb not in c.core}
    assert {(c.platform, limb, origin) for _, c, limb, origin in LIMBS} == every


@pytest.mark.parametrize(("name", "cat", "limb", "origin"), LIMBS, ids=[n for n, *_ in LIMBS])
def test_stick_headings_keep_their_side_on_every_shipped_limb(
    name: str, cat: Catalogue, limb: str, origin: str
) -> None:
    available = limbs.available_directions(limbs.direction_sets([cat], limb, origin))
    tips = limbs.tips_of([cat], limb, origin)
    assert available, name
    signs = {forward_sign(d) for d in available if d is not Direction.PLACE_MIDDLE}
    for k, horizontal in enumerate(RING):
        for level in Level:
            asked = pushed(k * 45.0, level)
            assert asked == Direction((horizontal.value, level.value)), "the mapping itself"
            got = limbs.served(asked, available, tips)
            where = (name, asked.slug, got.slug)
            if asked in available:
                assert got is asked, where
                continue
            sign = forward_sign(asked)
            if sign != 0 and sign in signs:
                assert forward_sign(got) == sign, where
            if sign == 0 and signs & {0, 1}:
                assert forward_sign(got) >= 0, where
            assert got is asked or got in available, where
            assert angle_between(asked, got) <= MAX_ANGLE_DEG + 1e-9, where


@pytest.mark.parametrize(("name", "cat", "limb", "origin"), LIMBS, ids=[n for n, *_ in LIMBS])
def test_the_client_drops_a_part_exactly_when_the_databank_would_refuse_it(
    name: str, cat: Catalogue, limb: str, origin: str
) -> None:
    """``servable`` (the client sends the drive alone when it is False) agrees with the real
    ECL on every stick heading and level: a part is dropped only when the databank would
    answer ``direction_unavailable``, never when it would serve it or a substitute; and what
    the client sends instead is what the databank would serve (both judge by the catalogue's
    measured tips)."""
    sets = limbs.direction_sets([cat], limb, origin)
    tips = limbs.tips_of([cat], limb, origin)
    ecl = ECLS[cat.platform]
    for k in range(len(RING)):
        for level in Level:
            asked = pushed(k * 45.0, level)
            try:
                pose = ecl.query(limb, origin, asked.slug, 3, False)
                answered = True
            except KinesphereError as exc:
                assert exc.code == "direction_unavailable", (name, asked.slug, exc)
                answered = False
            assert limbs.servable(asked, sets, tips) is answered, (name, asked.slug)
            if answered:
                got = limbs.served(asked, limbs.available_directions(sets), tips)
                assert got.slug == pose.direction, (name, asked.slug)


def test_the_packbot_sweep_is_served_as_asked() -> None:
    """The headline gesture: low + stick left/right on the PackBot arm, which reaches low to
    either side: sent as asked, no substitute."""
    pb = [CATALOGUES["packbot"]]
    arm = limbs.available_directions(limbs.direction_sets(pb, "limb_11", "distal_11"))
    tips = limbs.tips_of(pb, "limb_11", "distal_11")
    assert arm is not None and Direction.LEFT_LOW in arm
    assert limbs.served(pushed(90, Level.LOW), arm, tips) is Direction.LEFT_LOW
    assert limbs.served(pushed(-90, Level.LOW), arm, tips) is Direction.RIGHT_LOW


def test_a_neighbour_that_points_elsewhere_is_no_substitute() -> None:
    """NAO's head has forward-high, 45 degrees from place-high by label, but the neck tilts
    38.5 degrees only: its poses look 51 degrees away from straight up, so the client, like
    the databank, does not send it for place-high."""
    nao = [CATALOGUES["nao"]]
    head = limbs.direction_sets(nao, "limb_51", "distal_51")
    tips = limbs.tips_of(nao, "limb_51", "distal_51")
    available = limbs.available_directions(head)
    assert available is not None and Direction.FORWARD_HIGH in available
    assert limbs.served(Direction.PLACE_HIGH, available) is Direction.FORWARD_HIGH  # by label
    assert limbs.served(Direction.PLACE_HIGH, available, tips) is Direction.PLACE_HIGH  # as asked
    assert not limbs.servable(Direction.PLACE_HIGH, head, tips)


def test_without_a_catalogue_the_stick_goes_out_as_asked() -> None:
    assert limbs.served(Direction.LEFT_LOW, None) is Direction.LEFT_LOW
    assert limbs.served(Direction.PLACE_MIDDLE, frozenset({Direction.PLACE_HIGH})) is (
        Direction.PLACE_MIDDLE
    ), "neutral is never replaced"
    up = frozenset({Direction.PLACE_HIGH, Direction.FORWARD_HIGH})
    assert limbs.served(Direction.PLACE_LOW, up) is Direction.PLACE_LOW, "nothing honest: as asked"
    assert limbs.served(Direction.LEFT_MIDDLE, frozenset({Direction.FORWARD_MIDDLE})) is (
        Direction.LEFT_MIDDLE
    ), "a right angle is another movement, not a substitute"


def test_a_group_is_served_what_every_member_has() -> None:
    """Mixed platforms: the group moves together, on a direction all of them store."""
    cats = [CATALOGUES["packbot"], CATALOGUES["youbot"]]
    both = limbs.available_directions(limbs.direction_sets(cats, "limb_11", "distal_11"))
    assert both is not None
    for cat in cats:
        own = limbs.available_directions(limbs.direction_sets([cat], "limb_11", "distal_11"))
        assert own is not None and both <= own
    got = limbs.served(Direction.LEFT_LOW, both)
    assert got in both and forward_sign(got) >= 0
