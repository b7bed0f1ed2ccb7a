"""pygame input driven only by events posted into pygame's real queue (SDL dummy video driver):
controllers, raw joysticks, hot-plug and the keyboard fallback."""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

import pygame  # noqa: E402
import pytest  # noqa: E402

from kinesphere.clients.gamepad import mapfile  # noqa: E402
from kinesphere.clients.gamepad.inputs import pad  # noqa: E402
from kinesphere.clients.gamepad.mapping import MapperState, map_controls  # noqa: E402
from kinesphere.clients.gamepad.state import Action, ControllerState  # noqa: E402
from kinesphere.errors import KinesphereError  # noqa: E402
from kinesphere.laban import Direction  # noqa: E402
from support.clients import VirtualPad, post  # noqa: E402

MAX = 32767
CTRL = 7  # instance id of the posted "controller"
JOY = 9  # instance id of the posted raw joystick


pytestmark = pytest.mark.usefixtures("pygame_up")


def axis(a: int, value: int, iid: int = CTRL) -> None:
    post(pygame.CONTROLLERAXISMOTION, instance_id=iid, axis=a, value=value)


def button(b: int, down: bool = True, iid: int = CTRL) -> None:
    kind = pygame.CONTROLLERBUTTONDOWN if down else pygame.CONTROLLERBUTTONUP
    post(kind, instance_id=iid, button=b)


def key(k: int, down: bool = True) -> None:
    post(pygame.KEYDOWN if down else pygame.KEYUP, key=k, mod=0)


def direction(cs: ControllerState) -> tuple[Direction, float]:
    i = map_controls(cs, MapperState(), 0.0, mapfile.load().tuning)[0]
    return i.direction, i.size


def test_controller_axes_and_buttons(inp: pad.PygameInput) -> None:
    post(pygame.CONTROLLERDEVICEADDED, device_index=42, instance_id=CTRL)  # no such device
    axis(pygame.CONTROLLER_AXIS_RIGHTY, -MAX)  # right stick up
    axis(pygame.CONTROLLER_AXIS_TRIGGERRIGHT, MAX)
    button(pygame.CONTROLLER_BUTTON_LEFTSHOULDER)
    button(pygame.CONTROLLER_BUTTON_Y)
    cs = inp.poll()
    assert cs.source == "controller" and cs.connected
    assert cs.ry == -1.0 and cs.rt == 1.0
    assert cs.held == cs.pressed == {Action.DEADMAN, Action.TARGET_NEXT}
    assert direction(cs) == (Direction.FORWARD_HIGH, 3.0)
    button(pygame.CONTROLLER_BUTTON_Y, down=False)
    again = inp.poll()  # presses are one-shot, holds stay
    assert again.pressed == frozenset() and again.held == {Action.DEADMAN}
    button(pygame.CONTROLLER_BUTTON_LEFTSHOULDER, down=False)
    axis(pygame.CONTROLLER_AXIS_RIGHTY, 0)
    axis(pygame.CONTROLLER_AXIS_RIGHTX, -MAX // 2)
    cs = inp.poll()
    assert cs.held == frozenset()
    assert direction(cs)[0] is Direction.LEFT_HIGH


def test_a_tap_between_two_ticks_still_counts(inp: pad.PygameInput) -> None:
    button(pygame.CONTROLLER_BUTTON_B)
    button(pygame.CONTROLLER_BUTTON_B, down=False)
    cs = inp.poll()
    assert Action.ESTOP in cs.pressed and Action.ESTOP not in cs.held


def test_controllers_joy_events_are_ignored(inp: pad.PygameInput) -> None:
    """SDL reports a gamepad twice; its raw JOY* twin must not move anything."""
    axis(pygame.CONTROLLER_AXIS_LEFTX, 0)
    post(pygame.JOYAXISMOTION, instance_id=CTRL, axis=3, value=1.0)
    post(pygame.JOYBUTTONDOWN, instance_id=CTRL, button=4)
    cs = inp.poll()
    assert cs.rx == 0.0 and cs.held == frozenset()


def test_raw_joystick_uses_the_joystick_numbers(inp: pad.PygameInput) -> None:
    post(pygame.JOYDEVICEADDED, device_index=43, instance_id=JOY)
    cs = inp.poll()
    assert cs.lt == 0.0 and cs.rt == 0.0, "a released xpad trigger rests at -1"
    post(pygame.JOYAXISMOTION, instance_id=JOY, axis=3, value=-1.0)  # right x: left
    post(pygame.JOYAXISMOTION, instance_id=JOY, axis=2, value=1.0)  # left trigger in
    post(pygame.JOYBUTTONDOWN, instance_id=JOY, button=4)  # LB: deadman
    post(pygame.JOYHATMOTION, instance_id=JOY, hat=0, value=(1, 0))  # d-pad right: turn
    cs = inp.poll()
    assert cs.source == "joystick"
    assert cs.held == {Action.DEADMAN, Action.TURN_RIGHT}
    assert direction(cs) == (Direction.LEFT_LOW, 3.0)
    post(pygame.JOYHATMOTION, instance_id=JOY, hat=0, value=(0, -1))  # d-pad down: next limb
    cs = inp.poll()
    assert Action.TURN_RIGHT not in cs.held and Action.LIMB_NEXT in cs.pressed
    post(pygame.JOYHATMOTION, instance_id=JOY, hat=0, value=(0, 0))
    assert Action.LIMB_NEXT not in inp.poll().held


def test_unplugging_stops_everything_and_replugging_starts_released(
    inp: pad.PygameInput,
) -> None:
    post(pygame.CONTROLLERDEVICEADDED, device_index=44, instance_id=CTRL)
    button(pygame.CONTROLLER_BUTTON_LEFTSHOULDER)
    axis(pygame.CONTROLLER_AXIS_RIGHTX, MAX)
    assert inp.poll().held == {Action.DEADMAN}
    post(pygame.CONTROLLERDEVICEREMOVED, instance_id=CTRL)
    post(pygame.JOYDEVICEREMOVED, instance_id=CTRL)  # SDL sends both
    cs = inp.poll()
    assert not cs.connected and cs.held == frozenset() and cs.rx == 0.0
    assert not inp.poll().connected, "stays disconnected until a device comes back"
    post(pygame.CONTROLLERDEVICEADDED, device_index=44, instance_id=CTRL)
    cs = inp.poll()
    assert cs.connected and cs.held == frozenset(), "the deadman must be pressed anew"
    button(pygame.CONTROLLER_BUTTON_LEFTSHOULDER)
    assert inp.poll().held == {Action.DEADMAN}


def test_removing_an_idle_second_pad_changes_nothing(inp: pad.PygameInput) -> None:
    post(pygame.CONTROLLERDEVICEADDED, device_index=45, instance_id=CTRL)
    post(pygame.CONTROLLERDEVICEADDED, device_index=46, instance_id=CTRL + 1)
    button(pygame.CONTROLLER_BUTTON_LEFTSHOULDER)
    post(pygame.CONTROLLERDEVICEREMOVED, instance_id=CTRL + 1)
    cs = inp.poll()
    assert cs.connected and cs.held == {Action.DEADMAN}


def test_keyboard_offers_the_same_actions(inp: pad.PygameInput) -> None:
    key(pygame.K_UP)
    key(pygame.K_LEFT)
    key(pygame.K_SPACE)
    key(pygame.K_3)
    cs = inp.poll()
    assert cs.source == "keyboard" and cs.held == {Action.DEADMAN}
    assert direction(cs) == pytest.approx((Direction.LEFT_FORWARD_MIDDLE, 3.0), abs=1e-3)
    key(pygame.K_1)
    key(pygame.K_q)
    assert direction(inp.poll()) == pytest.approx((Direction.LEFT_FORWARD_LOW, 1.0), abs=1e-3)
    for k in (pygame.K_UP, pygame.K_LEFT):
        key(k, down=False)
    assert direction(inp.poll()) == pytest.approx((Direction.PLACE_LOW, 1.0), abs=1e-3)
    key(pygame.K_w)
    tuning = mapfile.load().tuning
    i = map_controls(inp.poll(), MapperState(), 0.0, tuning)[0]
    assert i.drive is not None and i.drive.direction == "forward-middle"
    assert i.drive.forward == tuning.drive_scale and not i.turbo
    key(pygame.K_LSHIFT)
    key(pygame.K_z)
    i = map_controls(inp.poll(), MapperState(), 0.0, tuning)[0]
    assert i.turbo and i.drive is not None
    assert (i.drive.forward, i.drive.yaw) == (tuning.drive_turbo, tuning.turn_turbo)
    for k in (pygame.K_w, pygame.K_LSHIFT, pygame.K_z):
        key(k, down=False)
    for k, action in [(pygame.K_ESCAPE, Action.ESTOP), (pygame.K_TAB, Action.LIMB_NEXT),
                      (pygame.K_l, Action.ORIGIN_NEXT), (pygame.K_t, Action.TARGET_NEXT),
                      (pygame.K_RETURN, Action.RELEASE), (pygame.K_F10, Action.QUIT)]:
        key(k)
        assert action in inp.poll().pressed
        key(k, down=False)


def test_losing_focus_releases_every_key(inp: pad.PygameInput) -> None:
    key(pygame.K_SPACE)
    key(pygame.K_RIGHT)
    assert inp.poll().held == {Action.DEADMAN}
    post(pygame.WINDOWFOCUSLOST)
    cs = inp.poll()
    assert cs.held == frozenset() and cs.rx == 0.0


def test_window_close_asks_to_quit(inp: pad.PygameInput) -> None:
    post(pygame.QUIT)
    assert Action.QUIT in inp.poll().pressed


def test_a_custom_mapping_moves_the_deadman(tmp_path: Path) -> None:
    f = tmp_path / "m.toml"
    f.write_text('[controller.buttons]\ndeadman = ["a"]\n[keyboard.buttons]\ndeadman = ["d"]\n'
                 '[keyboard]\ndrive_right = ["k"]\n')
    pygame.event.clear()
    inp = pad.PygameInput(mapfile.load(f))
    button(pygame.CONTROLLER_BUTTON_LEFTSHOULDER)
    assert inp.poll().held == frozenset()
    button(pygame.CONTROLLER_BUTTON_A)
    assert inp.poll().held == {Action.DEADMAN}


def test_unknown_key_names_are_explained(tmp_path: Path) -> None:
    f = tmp_path / "m.toml"
    f.write_text('[keyboard.buttons]\nestop = ["big red"]\n')
    with pytest.raises(KinesphereError, match="unknown key name 'big red'"):
        pad.PygameInput(mapfile.load(f))


def test_a_real_sdl_game_controller(inp: pad.PygameInput) -> None:
    """Through SDL's own joystick path: a virtual GameController attached with SDL's API."""
    vpad = VirtualPad()
    try:
        cs = inp.poll()  # SDL reports it added; the input opens it as a controller
        # (SDL names it after the first mapping made for its GUID: not checked here)
        assert cs.connected and [d.kind for d in inp.devices.values()] == ["controller"]
        vpad.deadman()
        vpad.axis(pygame.CONTROLLER_AXIS_TRIGGERLEFT, 1.0)
        vpad.right(-1.0, 0.0)
        vpad.left(0.0, -0.6)
        vpad.button(pygame.CONTROLLER_BUTTON_DPAD_LEFT)
        cs = inp.poll()
        assert cs.source == "controller"
        assert cs.held == {Action.DEADMAN, Action.TURN_LEFT}
        assert (cs.rx, cs.lt) == (-1.0, 1.0) and cs.ly == pytest.approx(-0.6, abs=1e-3)
        assert direction(cs) == (Direction.LEFT_LOW, 3.0)
        vpad.axis(pygame.CONTROLLER_AXIS_TRIGGERLEFT, 0.0)
        vpad.button(pygame.CONTROLLER_BUTTON_DPAD_LEFT, down=False)
        vpad.unplug()
        cs = inp.poll()
        assert not cs.connected and cs.held == frozenset() and cs.lt == 0.0
    finally:
        vpad.unplug()


@pytest.mark.parametrize("action", [Action.RELEASE, Action.TAKE, Action.ESTOP, Action.DEADMAN])
def test_the_keys_and_buttons_the_hud_names_do_what_it_says(
    inp: pad.PygameInput, action: Action
) -> None:
    """The HUD says 'press Enter' on the keyboard and 'press Start' on a pad: pressing what it
    names (spelled back into pygame's and SDL's names) is that action."""
    m = mapfile.load()
    named = m.press(action, "keyboard").split(" or ")
    by_words = {v: k for k, v in mapfile.KEY_NAMES.items()}
    for word in named:
        key(pygame.key.key_code(by_words.get(word, word.lower())))
        cs = inp.poll()
        assert action in cs.pressed | cs.held, (action, word)
        inp.keys.clear()
    pads = {v: k for k, v in mapfile.PAD_NAMES.items()}
    for word in m.press(action, "controller").split(" or "):
        name = pads.get(word, word.lower())
        button(mapfile.CONTROLLER_BUTTONS[name])
        cs = inp.poll()
        assert action in cs.pressed | cs.held, (action, word)
        button(mapfile.CONTROLLER_BUTTONS[name], down=False)
        inp.poll()
