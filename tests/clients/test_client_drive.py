"""The base drive: proportional, per base kind (holonomic or arcade), turn buttons, turbo,
and the version-1 fields that older robots read; base kinds from the shipped catalogues."""

from __future__ import annotations

import math

import pytest

from kinesphere.clients.gamepad.drive import Steering, base_kind, drive_of, steering_for
from kinesphere.clients.gamepad.state import Action, ControllerState
from kinesphere.clients.gamepad.sticks import Tuning
from kinesphere.laban import Direction
from kinesphere.protocol import Drive

T = Tuning()
HALF = T.stick_deadzone + (T.rim - T.stick_deadzone) / 2
"""A stick deflection that reads as half way to the rim."""


def drive(steering: Steering, lx: float = 0.0, ly: float = 0.0, *held: str) -> Drive | None:
    cs = ControllerState(lx=lx, ly=ly, held=frozenset(held))
    return drive_of(cs, None, steering, T)[0]


def test_holonomic_stick_is_the_body_velocity() -> None:
    d = drive(Steering.HOLONOMIC, 0.0, -1.0)  # up: forward
    assert d is not None and (d.forward, d.left, d.yaw) == (T.drive_scale, 0.0, 0.0)
    d = drive(Steering.HOLONOMIC, -HALF, 0.0)  # half left: slide left at half the scale
    assert d is not None and d.forward == 0.0
    assert d.left == pytest.approx(T.drive_scale / 2, abs=1e-3)
    s = math.sqrt(0.5)
    d = drive(Steering.HOLONOMIC, -s, -s)  # up-left: diagonal, proportional
    assert d is not None and d.forward == pytest.approx(d.left) and d.forward > 0
    assert math.hypot(d.forward, d.left) == pytest.approx(T.drive_scale, abs=1e-3)
    assert (d.direction, d.speed) == pytest.approx(("left-forward-middle", T.drive_scale))


def test_arcade_stick_drives_forward_and_turns() -> None:
    d = drive(Steering.ARCADE, -1.0, 0.0)  # full left: turn left in place, no sideways slide
    assert d is not None and (d.forward, d.left, d.yaw) == (0.0, 0.0, T.turn_scale)
    d = drive(Steering.ARCADE, 1.0, 0.0)
    assert d is not None and d.yaw == -T.turn_scale, "right turns clockwise"
    s = math.sqrt(0.5)
    d = drive(Steering.ARCADE, -s, -s)  # up-left: an arc to the left
    assert d is not None and d.forward > 0 and d.yaw > 0 and d.left == 0.0
    # version-1 robots turn a diff base with the lateral component: the same arc for them
    assert d.direction == "left-forward-middle"


def test_turn_buttons_turn_every_mobile_base() -> None:
    for steering in (Steering.HOLONOMIC, Steering.ARCADE):
        left = drive(steering, 0.0, 0.0, Action.TURN_LEFT)
        right = drive(steering, 0.0, 0.0, Action.TURN_RIGHT)
        assert left is not None and left.yaw == T.turn_scale and left.forward == 0.0
        assert right is not None and right.yaw == -T.turn_scale
        both = drive(steering, 0.0, 0.0, Action.TURN_LEFT, Action.TURN_RIGHT)
        assert both is None, "both held cancel out"
    d = drive(Steering.HOLONOMIC, -1.0, -1.0, Action.TURN_RIGHT)  # drive diagonally, turning
    assert d is not None and d.forward > 0 and d.left > 0 and d.yaw < 0


def test_a_pure_turn_of_a_holonomic_base_has_no_version_1_form() -> None:
    d = drive(Steering.HOLONOMIC, 0.0, 0.0, Action.TURN_LEFT)
    assert d is not None and (d.direction, d.speed) == ("", 0.0) and d.is_continuous


def test_turbo_swaps_in_the_turbo_scales() -> None:
    d = drive(Steering.ARCADE, 0.0, -1.0, Action.TURBO, Action.TURN_LEFT)
    assert d is not None and (d.forward, d.yaw) == (T.drive_turbo, T.turn_turbo)
    slow = Tuning(drive_scale=0.2, turn_scale=0.1)
    cs = ControllerState(ly=-1.0, held=frozenset({Action.TURN_LEFT}))
    d = drive_of(cs, None, Steering.HOLONOMIC, slow)[0]
    assert d is not None and (d.forward, d.yaw) == (0.2, 0.1)


def test_fixed_bases_get_no_drive_and_the_dead_zone_is_still() -> None:
    assert drive(Steering.NONE, 0.0, -1.0, Action.TURN_LEFT) is None
    assert drive(Steering.HOLONOMIC, 0.1, 0.0) is None


def test_values_stay_within_the_wire_bounds() -> None:
    for lx in (-1.0, -0.5, 0.0, 0.5, 1.0):
        for ly in (-1.0, 0.0, 1.0):
            for held in ((), (Action.TURBO, Action.TURN_LEFT), (Action.TURN_RIGHT,)):
                for steering in (Steering.HOLONOMIC, Steering.ARCADE):
                    d = drive(steering, lx, ly, *held)
                    if d is not None:
                        assert all(-1 <= v <= 1 for v in (d.forward, d.left, d.yaw))
                        assert 0 <= d.speed <= 1
                        assert not d.direction or Direction.parse(d.direction).is_translation


def test_steering_follows_the_targets_base_kinds() -> None:
    assert steering_for([]) is Steering.HOLONOMIC
    assert steering_for(["fixed"]) is Steering.NONE
    assert steering_for(["skid"]) is Steering.ARCADE
    assert steering_for(["diff", "skid", "fixed"]) is Steering.ARCADE
    assert steering_for(["omni"]) is Steering.HOLONOMIC
    assert steering_for(["omni", "skid"]) is Steering.HOLONOMIC, "mixed: diff ignores left"
    assert steering_for(["unknown"]) is Steering.HOLONOMIC


def test_base_kinds_of_the_shipped_platforms() -> None:
    from kinesphere.platforms.platform import load_platform
    from kinesphere.services.ecl.ecl import Ecl

    for p in ("baxter", "nao", "youbot", "packbot", "khepera"):
        cat = Ecl.open(p).catalogue()
        kind = base_kind(cat)
        if cat.base_kind:
            assert kind == load_platform(p).base.kind
        else:  # a databank from before base_kind: fixed or not, from can_translate
            assert kind == ("unknown" if cat.can_translate else "fixed")
        assert (kind == "fixed") == (load_platform(p).base.kind == "fixed")
