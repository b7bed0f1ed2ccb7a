"""The intent-preserving substitution rule, against the shipped catalogues of every platform."""

from __future__ import annotations

import random

import pytest

from kinesphere.laban import Direction
from kinesphere.platforms.platform import platform_names
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.substitution import angle_between, forward_sign, nearest_direction


def shipped_limbs() -> list[tuple[str, str, frozenset[Direction]]]:
    out = []
    for platform in platform_names():
        catalogue = Ecl.open(platform).catalogue()
        for entry in catalogue.limbs:
            dirs = frozenset(Direction.parse(d) for d in entry.directions)
            out.append((f"{platform}/{entry.limb}/{entry.origin}", platform, dirs))
    return out


LIMBS = shipped_limbs()


def test_every_articulated_platform_contributes() -> None:
    assert {p for _, p, _ in LIMBS} >= {"baxter", "nao", "youbot", "packbot"}


def test_a_lateral_low_push_stays_in_front() -> None:
    """Left/right + low on NAO's right arm, which cannot reach across to its left-low: served
    in front, never from behind."""
    arm = next(d for name, _, d in LIMBS if name == "nao/limb_11/distal_11")
    assert Direction.LEFT_LOW not in arm
    left = nearest_direction(Direction.LEFT_LOW, arm)
    assert left is not None and left.direction is Direction.LEFT_FORWARD_LOW
    assert left.angle == pytest.approx(35.26, abs=0.01)
    sweep = next(d for name, _, d in LIMBS if name == "packbot/limb_11/distal_11")
    assert {Direction.LEFT_LOW, Direction.RIGHT_LOW} <= sweep  # PackBot's sweep: exact


@pytest.mark.parametrize(("name", "platform", "available"), LIMBS, ids=[n for n, _, _ in LIMBS])
def test_rule_on_every_shipped_limb(name: str, platform: str, available: frozenset[Direction]
                                    ) -> None:
    signs = {forward_sign(d) for d in available if d is not Direction.PLACE_MIDDLE}
    for requested in Direction:
        choice = nearest_direction(requested, available)
        if requested in available:
            assert choice is not None and choice.direction is requested and choice.angle == 0
            continue
        if requested is Direction.PLACE_MIDDLE:
            assert choice is None
            continue
        sign = forward_sign(requested)
        if choice is None:  # only when nothing lies on an admissible side
            assert not (signs & ({sign, 0} if sign else {0, 1})), (name, requested)
            continue
        got = forward_sign(choice.direction)
        assert got != -sign or sign == 0, (name, requested, choice)  # never the opposite side
        if sign != 0 and sign in signs:  # a front (back) request stays in front (behind)
            assert got == sign, (name, requested, choice)
        if sign == 0:  # a lateral or vertical request is never served from behind
            assert got >= 0, (name, requested, choice)
        # nothing admissible is strictly nearer
        admissible = [d for d in available if d is not Direction.PLACE_MIDDLE
                      and forward_sign(d) == got]
        assert all(angle_between(requested, d) >= choice.angle - 1e-9 for d in admissible)


def test_choice_does_not_depend_on_input_order() -> None:
    rng = random.Random(7)
    for _, _, available in LIMBS:
        items = list(available)
        for requested in Direction:
            first = nearest_direction(requested, items)
            rng.shuffle(items)
            assert nearest_direction(requested, items) == first


def test_angular_limit() -> None:
    available = [Direction.FORWARD_MIDDLE]
    assert nearest_direction(Direction.FORWARD_HIGH, available, max_angle=44.0) is None
    choice = nearest_direction(Direction.FORWARD_HIGH, available, max_angle=45.0)
    assert choice is not None and choice.direction is Direction.FORWARD_MIDDLE


def test_ties_prefer_front_then_level() -> None:
    # left-middle is 45 deg from both left-forward-middle and left-back-middle: front wins
    choice = nearest_direction(Direction.LEFT_MIDDLE,
                               [Direction.LEFT_BACK_MIDDLE, Direction.LEFT_FORWARD_MIDDLE])
    assert choice is not None and choice.direction is Direction.LEFT_FORWARD_MIDDLE
    # place-high is equally far from left-high and right-high... and from forward-high: front
    choice = nearest_direction(Direction.PLACE_HIGH,
                               [Direction.RIGHT_HIGH, Direction.LEFT_HIGH, Direction.FORWARD_HIGH])
    assert choice is not None and choice.direction is Direction.FORWARD_HIGH
    # same angle and same forward component: the commanded level wins
    choice = nearest_direction(Direction.LEFT_FORWARD_MIDDLE,
                               [Direction.LEFT_HIGH, Direction.LEFT_MIDDLE])
    assert choice is not None and choice.direction is Direction.LEFT_MIDDLE
