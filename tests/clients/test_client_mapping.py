"""The pure mapping: stick sectors, levels, sizes, hysteresis, beyond, drive; the mapping file."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from kinesphere.clients.gamepad import mapfile
from kinesphere.clients.gamepad.mapping import Intent, MapperState, map_controls
from kinesphere.clients.gamepad.state import Action, ControllerState
from kinesphere.clients.gamepad.sticks import Tuning
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from support.files import refused

T = Tuning()


def stick(angle_deg: float, mag: float = 1.0, held: frozenset[str] = frozenset(),
          lt: float = 0.0, rt: float = 0.0) -> ControllerState:
    """Right stick pushed towards ``angle_deg`` (0 = up/forward, 90 = left), SDL axes, with
    the actions ``held`` and the triggers ``lt``, ``rt``."""
    a = math.radians(angle_deg)
    fwd, left = mag * math.cos(a), mag * math.sin(a)
    return ControllerState(rx=-left, ry=-fwd, lt=lt, rt=rt, held=held)


def intent(cs: ControllerState, prev: MapperState | None = None, dt: float = 1 / 30) -> Intent:
    return map_controls(cs, prev or MapperState(), dt, T)[0]


@pytest.mark.parametrize(
    ("angle", "slug"),
    [
        (0, "forward-middle"),
        (45, "left-forward-middle"),
        (90, "left-middle"),
        (135, "left-back-middle"),
        (180, "back-middle"),
        (-135, "right-back-middle"),
        (-90, "right-middle"),
        (-45, "right-forward-middle"),
        (20, "forward-middle"),  # nearest sector
        (25, "left-forward-middle"),
        (-170, "back-middle"),
    ],
)
def test_stick_angle_picks_the_nearest_horizontal(angle: float, slug: str) -> None:
    assert intent(stick(angle)).direction.slug == slug


def test_screen_convention_stick_up_is_forward_and_left_is_left() -> None:
    assert intent(ControllerState(ry=-1.0)).direction is Direction.FORWARD_MIDDLE
    assert intent(ControllerState(rx=-1.0)).direction is Direction.LEFT_MIDDLE
    assert intent(ControllerState(rx=1.0, ry=1.0)).direction is Direction.RIGHT_BACK_MIDDLE


@pytest.mark.parametrize(
    ("lt", "rt", "level"),
    [(0.0, 0.0, "middle"), (1.0, 0.0, "low"), (0.0, 1.0, "high"), (0.2, 0.0, "middle"),
     (0.9, 0.5, "low"), (0.5, 0.9, "high")],
)
def test_triggers_pick_the_level(lt: float, rt: float, level: str) -> None:
    i = intent(stick(90, lt=lt, rt=rt))
    assert i.direction.slug == f"left-{level}"


def test_centred_stick_is_place_and_a_trigger_alone_reaches_up_or_down() -> None:
    assert intent(ControllerState()) == Intent()
    assert intent(ControllerState()).direction is Direction.PLACE_MIDDLE
    low = intent(ControllerState(lt=0.5))
    assert (low.direction, low.size) == (Direction.PLACE_LOW, 1.5)
    high = intent(ControllerState(rt=1.0))
    assert (high.direction, high.size) == (Direction.PLACE_HIGH, 3.0)


def test_deflection_maps_continuously_to_size() -> None:
    dz, rim = T.stick_deadzone, T.rim
    assert intent(stick(0, dz * 0.9)).size == 0.0
    assert intent(stick(0, dz * 0.9)).direction is Direction.PLACE_MIDDLE
    for k in (1, 2, 3):  # near, mid, far
        assert intent(stick(0, dz + (rim - dz) * k / 3)).size == pytest.approx(k, abs=1e-3)
    assert intent(stick(0, 1.0)).size == 3.0
    sizes = [intent(stick(0, m / 100)).size for m in range(0, 101)]
    assert sizes == sorted(sizes)
    assert max(b - a for a, b in zip(sizes, sizes[1:], strict=False)) < 0.05  # no jumps


def test_hysteresis_keeps_the_direction_on_a_boundary() -> None:
    state = MapperState()
    seen = []
    # Forward, then jitter around the forward/left-forward boundary (22.5 deg) by +-8 deg.
    for angle in [0, 15, 30, 15, 30, 14.5, 30.5, 20, 31, 22.5]:
        i, state = map_controls(stick(angle), state, 1 / 30, T)
        seen.append(i.direction.slug)
    assert set(seen) == {"forward-middle"}
    i, state = map_controls(stick(33), state, 1 / 30, T)  # past 22.5 + 10
    assert i.direction.slug == "left-forward-middle"
    i, state = map_controls(stick(14), state, 1 / 30, T)  # now the other way round
    assert i.direction.slug == "left-forward-middle"
    i, state = map_controls(stick(11), state, 1 / 30, T)
    assert i.direction.slug == "forward-middle"


def test_without_hysteresis_the_same_jitter_flickers() -> None:
    flat = Tuning(hysteresis_deg=0.0)
    state, seen = MapperState(), []
    for angle in [15, 30, 15, 30]:
        i, state = map_controls(stick(angle), state, 1 / 30, flat)
        seen.append(i.direction.slug)
    assert seen == ["forward-middle", "left-forward-middle"] * 2


def test_returning_to_centre_forgets_the_sector() -> None:
    _, state = map_controls(stick(30), MapperState(), 0.0, T)
    _, state = map_controls(ControllerState(), state, 0.0, T)
    assert state.limb_sector is None
    assert intent(stick(30), state).direction.slug == "left-forward-middle"


def test_beyond_grows_past_far_while_held_at_the_rim() -> None:
    held = frozenset({Action.BEYOND})
    state = MapperState()
    sizes = []
    for _ in range(30):  # one second at 30 Hz
        i, state = map_controls(stick(90, held=held), state, 1 / 30, T)
        sizes.append(i.size)
    assert sizes[0] == pytest.approx(3.0 + T.beyond_rate / 30, abs=1e-3)
    assert sizes[-1] == pytest.approx(3.0 + T.beyond_rate, abs=1e-3)
    assert i.beyond
    for _ in range(200):
        i, state = map_controls(stick(90, held=held), state, 1 / 30, T)
    assert i.size == 3.0 + T.beyond_max
    i, state = map_controls(stick(90), state, 1 / 30, T)  # released
    assert i.size == 3.0 and not i.beyond
    i, state = map_controls(stick(90, 0.6, held=held), state, 1 / 30, T)  # not at the rim
    assert i.size < 3.0 and not i.beyond


def test_left_stick_drives_the_base() -> None:
    """Holonomic by default; the full mapping per base kind is in test_client_drive."""
    assert intent(ControllerState()).drive is None
    i = intent(ControllerState(ly=-1.0))
    assert i.drive is not None and (i.drive.forward, i.drive.left, i.drive.yaw) == (0.5, 0, 0)
    assert (i.drive.direction, i.drive.speed) == ("forward-middle", 0.5)
    assert intent(ControllerState(lx=0.1)).drive is None  # dead zone


def test_both_sticks_at_once() -> None:
    """The sweep gesture: arm left-low, far, while driving forward."""
    i = intent(ControllerState(rx=-1.0, lt=1.0, ly=-0.6, held=frozenset({Action.DEADMAN})))
    assert i.direction is Direction.LEFT_LOW and i.size == 3.0
    assert i.drive is not None and i.drive.direction == "forward-middle"
    assert i.deadman and i.moving


def test_disconnected_is_neutral() -> None:
    cs = ControllerState(rx=-1.0, held=frozenset({Action.DEADMAN}), connected=False)
    i, state = map_controls(cs, MapperState(limb_sector=2, extra=1.0), 0.1, T)
    assert i == Intent() and state == MapperState()


def test_bad_tuning_is_explained() -> None:
    with pytest.raises(KinesphereError, match="stick_deadzone"):
        Tuning(stick_deadzone=0.99)
    with pytest.raises(KinesphereError, match="hysteresis_deg"):
        Tuning(hysteresis_deg=30)


# --- the mapping file -------------------------------------------------------------------------


def test_default_mapping_loads() -> None:
    m = mapfile.load()
    assert m.tuning == Tuning()
    assert m.controller.buttons["deadman"] == (mapfile.CONTROLLER_BUTTONS["leftshoulder"],)
    assert m.controller.axes["low"] == mapfile.CONTROLLER_AXES["lefttrigger"]
    assert m.joystick.hats["limb_next"] == ((0, "down"),)
    assert m.joystick.hats["turn_right"] == ((0, "right"),)
    assert m.controller.buttons["turn_left"] == (mapfile.CONTROLLER_BUTTONS["dpleft"],)
    assert m.controller.buttons["turbo"] == (mapfile.CONTROLLER_BUTTONS["leftstick"],)
    assert m.keyboard.buttons["deadman"] == ("space",)


def test_a_user_mapping_overrides_only_what_it_names(tmp_path: Path) -> None:
    f = tmp_path / "mine.toml"
    f.write_text(
        '[tuning]\nstick_deadzone = 0.2\n[controller.buttons]\ndeadman = ["a", "paddle1"]\n'
    )
    m = mapfile.load(f)
    assert m.tuning.stick_deadzone == 0.2 and m.tuning.rim == Tuning().rim
    assert m.controller.buttons["deadman"] == (0, 16)
    assert m.controller.buttons["beyond"] == (mapfile.CONTROLLER_BUTTONS["rightshoulder"],)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ('[controller.buttons]\ndeadman = ["lb"]', "'lb'; valid: a, b, back"),
        ('[controller]\nlow = "trigger"', "lefttrigger"),
        ('[controller.buttons]\ndeadmen = ["a"]', "unknown deadmen"),
        ('[tuning]\nrim = "far"', "rim must be a number"),
        ('[joystick.buttons]\nestop = ["hat0_sideways"]', "hatN_left"),
        ('[groups]\narms = ["baxter-1"]', "--target group:NAME"),
        ("[extras]\nx = 1", "unknown extras"),
        ("not toml [", "is not TOML"),
    ],
)
def test_bad_mapping_files_are_explained(tmp_path: Path, text: str, match: str) -> None:
    assert re.search(match, refused(mapfile.load, tmp_path, text).message)
