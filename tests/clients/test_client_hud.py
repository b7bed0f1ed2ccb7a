"""The HUD on a virtual X server (Xvfb), through SDL's x11 driver, as a user would see it:
screenshots are taken from the X server, not from pygame's surface. The commanded cell is lit
where the stick points, missing directions are crossed out, every cell says its direction in
words, the robot's answer is on the screen and its letters are the tallest after the target's,
and statuses are in operator words and never cut off (``KINESPHERE_HUD_PNG=path`` keeps a
screenshot to look at)."""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Iterator
from typing import TypedDict, Unpack

import msgspec
import pygame
import pytest

from kinesphere.clients import targets as tg
from kinesphere.clients.gamepad import hud
from kinesphere.clients.gamepad.drive import Steering
from kinesphere.clients.gamepad.mapping import Intent, MapperState, map_controls
from kinesphere.clients.gamepad.readout import Readout
from kinesphere.clients.gamepad.state import ControllerState
from kinesphere.clients.gamepad.sticks import Tuning
from kinesphere.clients.gamepad.symbols import draw_symbol
from kinesphere.clients.link import AckAnswer, Seen
from kinesphere.laban import Direction, Horizontal, Level
from kinesphere.protocol import Ack, AckStage, Drive, RobotState, Substitution
from support.xserver import screenshot, sdl_window_on, virtual_display

pytestmark = pytest.mark.processes  # Xvfb


@pytest.fixture(scope="module")
def display() -> Iterator[str]:
    """A virtual X screen the size of the HUD, pygame's display on it."""
    with virtual_display(hud.SIZE) as name, sdl_window_on(name):
        yield name


@pytest.fixture(scope="module")
def window(display: str) -> Iterator[hud.Hud]:
    yield hud.Hud()


def shown(window: hud.Hud, display: str, readout: Readout) -> pygame.Surface:
    """The HUD draws ``readout`` in its window (a frame as the gamepad draws it); what the X
    server then shows."""
    window._last = 0.0
    window.draw(readout)
    shot = screenshot(display)
    assert shot.get_size() == hud.SIZE
    return shot


def state(robot_id: str, platform: str, status: str, **kw: object) -> Seen:
    st = RobotState(robot_id=robot_id, platform=platform, seq=1, stamp_ns=time.time_ns(),
                    joint_names=["a"], q=[0.0], qd=[0.0], base_pose=[0.0, 0.0, 0.0],
                    status=status, last_command_seq=7)
    return Seen(msgspec.structs.replace(st, **kw), time.monotonic())


def answer(robot_id: str, seq: int, stage: AckStage, **kw: object) -> AckAnswer:
    ack = Ack(robot_id=robot_id, sender="gamepad-me", seq=seq, stage=stage,
              stamp_ns=time.time_ns())
    return AckAnswer(msgspec.structs.replace(ack, **kw), time.monotonic())


class ReadoutChanges(TypedDict, total=False):
    """Fields of :class:`Readout` a test sets on the busy example of :func:`view`."""

    target: tg.Target
    members: list[str]
    answers: dict[str, AckAnswer]
    aliases: dict[str, str]
    intent: Intent
    engaged: bool
    deadman_required: bool
    remote_estop: list[str]
    need_fresh_deadman: bool
    connected: bool
    robots: dict[str, Seen]
    catalogue_errors: dict[str, str]
    available: frozenset[Direction] | None
    asked: Direction | None
    limb_holds: bool


def view(**kw: Unpack[ReadoutChanges]) -> Readout:
    """A busy HUD: a group of two PackBots, every robot status and answer at once."""
    base = Readout(
        target=tg.group("sweepers"), members=["packbot-1", "packbot-2"],
        limb="limb_11", origin="distal_11",
        aliases={"limb_11": "arm", "distal_11": "shoulder"},
        intent=Intent(direction=Direction.LEFT_LOW, size=2.4, deadman=True, reach=0.8,
                      drive=Drive(direction="forward-middle", speed=0.6, forward=0.6, yaw=0.3),
                      steering=Steering.ARCADE),
        engaged=True, deadman_required=True, estopped=False, remote_estop=[],
        need_fresh_deadman=False, connected=True, source="controller",
        robots={
            "packbot-1": state("packbot-1", "packbot", "moving", groups=["sweepers"]),
            "packbot-2": state("packbot-2", "packbot", "clamped", clamped=["turret"],
                               groups=["sweepers"], detail="turret target clamped to its limit"),
            "baxter-1": state("baxter-1", "baxter", "holding"),
            "nao-1": state("nao-1", "nao", "databank_unreachable",
                           detail="no databank answers kinesphere/ecl/nao/catalogue"),
            "youbot-1": state("youbot-1", "youbot", "estop", detail="e-stop latched",
                              estop_by="gamepad-me"),
        },
        seq=1234, message="target: group sweepers (packbot-1, packbot-2)", sender="gamepad-me",
        answers={
            "packbot-1": answer("packbot-1", 1233, AckStage.MOVING, substitutions=[
                Substitution("limb_11", "distal_11", "left-low", "left-forward-low", 35.3)]),
            "packbot-2": answer("packbot-2", 1233, AckStage.REJECTED, code="lease_held",
                                detail="alice@laptop holds this robot's lease"),
        },
        notice="packbot-2 refuses your commands: alice@laptop holds this robot's lease; "
               "press Back to take control",
        presses={"release": "Start", "deadman": "LB", "take": "Back", "estop": "B"},
        input_name="kinesphere virtual pad (game controller)",
    )
    return dataclasses.replace(base, **kw)


def rgb(surf: pygame.Surface, at: tuple[int, int]) -> tuple[int, int, int]:
    """The colour of one pixel, without its alpha."""
    c = surf.get_at(at)
    return c.r, c.g, c.b


def cell_centre(d: Direction) -> tuple[int, int]:
    """A point inside the cell's background, off the symbol."""
    r = hud.cell_rect(d)
    return r.left + 3, r.top + 3


def lit_cells(surf: pygame.Surface) -> list[Direction]:
    return [d for d in Direction if rgb(surf, cell_centre(d)) == hud.LIT]


def test_the_chart_is_laid_out_as_the_stick_points() -> None:
    """Seen from above, robot facing up: left is left, forward is up, in every level's block."""
    for lvl in ("high", "middle", "low"):
        c = {h: hud.cell_rect(Direction((h, lvl))).center for h in
             ("left", "place", "right", "forward", "back", "left-forward", "right-back")}
        assert c["left"][0] < c["place"][0] < c["right"][0]
        assert c["forward"][1] < c["place"][1] < c["back"][1]
        assert c["left-forward"][0] < c["place"][0] and c["left-forward"][1] < c["place"][1]
        assert c["right-back"][0] > c["place"][0] and c["right-back"][1] > c["place"][1]
    high, low = hud.cell_rect(Direction.PLACE_HIGH), hud.cell_rect(Direction.PLACE_LOW)
    assert high.right < low.left, "blocks side by side: high, middle, low"


@pytest.mark.parametrize(("sx", "sy", "side"), [(-1.0, 0.0, "left"), (1.0, 0.0, "right"),
                                                (0.0, -1.0, "up"), (0.0, 1.0, "down")])
def test_pushing_the_stick_lights_the_cell_on_that_side(
    window: hud.Hud, display: str, sx: float, sy: float, side: str
) -> None:
    intent = map_controls(ControllerState(rx=sx, ry=sy, lt=1.0), MapperState(), 0.0, Tuning())[0]
    (lit,) = lit_cells(shown(window, display, view(intent=intent)))
    x, y = hud.cell_rect(lit).center
    px, py = hud.cell_rect(Direction.PLACE_LOW).center
    assert {"left": x < px, "right": x > px, "up": y < py, "down": y > py}[side], lit


def diagonals(surf: pygame.Surface, d: Direction) -> list[tuple[int, int, int]]:
    """The colours along both diagonals of ``d``'s cell, corner to corner."""
    r = hud.cell_rect(d).inflate(-6, -6)
    n = r.width - 8
    return ([rgb(surf, (r.left + 4 + k, r.top + 4 + k)) for k in range(n)]
            + [rgb(surf, (r.right - 5 - k, r.top + 4 + k)) for k in range(n)])


def crossed(surf: pygame.Surface, d: Direction, colour: tuple[int, int, int]) -> bool:
    """Crossed out corner to corner: most of both diagonals is the cross's colour (the word
    and symbol may cover a little)."""
    line = diagonals(surf, d)
    return sum(c == colour for c in line) > 0.8 * len(line)


def test_missing_directions_are_crossed_out_corner_to_corner(
    window: hud.Hud, display: str,
) -> None:
    have = frozenset({Direction.LEFT_FORWARD_LOW, Direction.FORWARD_LOW, Direction.PLACE_HIGH})
    surf = shown(window, display, view(
        available=have, asked=Direction.LEFT_LOW,
        intent=Intent(direction=Direction.LEFT_FORWARD_LOW, size=3.0, deadman=True)))
    for d in Direction:
        r = hud.cell_rect(d)
        bg = rgb(surf, (r.left + 3, r.top + 12))
        if d is Direction.LEFT_FORWARD_LOW:
            assert bg == hud.LIT
        elif d in have or d is Direction.PLACE_MIDDLE:
            assert bg == hud.CELL_BG, d
            assert not crossed(surf, d, hud.UNAVAILABLE) and not crossed(surf, d, hud.BAD), d
        else:
            cross = hud.BAD if d is Direction.LEFT_LOW else hud.UNAVAILABLE
            assert crossed(surf, d, cross), d


def test_the_commanded_cell_is_lit(window: hud.Hud, display: str) -> None:
    shot = shown(window, display, view())
    lit = rgb(shot, cell_centre(Direction.LEFT_LOW))
    other = rgb(shot, cell_centre(Direction.RIGHT_HIGH))
    assert lit == hud.LIT and other == hud.CELL_BG
    keep = os.environ.get("KINESPHERE_HUD_PNG")
    if keep:
        pygame.image.save(shot, keep)
    shot = shown(window, display, view(engaged=False))
    assert rgb(shot, cell_centre(Direction.LEFT_LOW)) == hud.DIM


def test_status_lines_wrap_and_are_never_cut_off(window: hud.Hud) -> None:
    """Every word of a long status comes out, each piece within the column."""
    font, width = window.fonts["small"], 300
    text = ("E-STOP latched by a-very-long-operator-name@laboratory-workstation-17: release with "
            "kinesphere estop --release --target packbot-field-unit-0042-with-a-long-id")
    pieces = hud.wrap(font, text, width)
    assert len(pieces) > 2 and all(font.size(p)[0] <= width for p in pieces)
    assert "".join(pieces).replace(" ", "") == text.replace(" ", "")


def test_level_shading_follows_laban(window: hud.Hud) -> None:
    """Low filled, middle a dot, high striped: count ink inside each symbol."""
    surf = pygame.Surface((60, 80))
    inks = {}
    for lvl in Level:
        surf.fill(hud.BG)
        draw_symbol(surf, Direction((Horizontal.PLACE.value, lvl.value)),
                        pygame.Rect(10, 10, 40, 60), hud.INK)
        inks[lvl] = sum(rgb(surf, (x, y)) == hud.INK for x in range(13, 48)
                        for y in range(13, 68))
    assert inks[Level.LOW] > inks[Level.HIGH] > inks[Level.MIDDLE] > 0


@pytest.mark.parametrize(
    "kw",
    [
        {"estopped": True, "engaged": False},
        {"remote_estop": ["youbot-1"], "engaged": False},
        {"connected": False, "engaged": False},
        {"deadman_required": False},
        {"need_fresh_deadman": True, "engaged": False},
        {"robots": {}, "intent": Intent(), "target": tg.ALL, "aliases": {}},
        {"intent": Intent(direction=Direction.RIGHT_FORWARD_HIGH, size=4.5, beyond=True)},
        {"catalogue_errors": {"nao": "no databank answers"}},
        {
            "available": frozenset({Direction.LEFT_FORWARD_LOW, Direction.BACK_HIGH}),
            "asked": Direction.LEFT_LOW,
            "intent": Intent(direction=Direction.LEFT_FORWARD_LOW, size=3.0, deadman=True),
        },
    ],
)
def test_every_state_renders(window: hud.Hud, kw: ReadoutChanges) -> None:
    window._last = 0.0
    window.draw(view(**kw))


def test_a_direction_with_no_pose_near_is_crossed_out_in_red_while_driving(
    window: hud.Hud, display: str,
) -> None:
    """The stick points where no targeted body has a pose within the limit: its lit cell is
    crossed out in the refusal colour (the command carries the drive alone)."""
    have = frozenset({Direction.LEFT_FORWARD_LOW, Direction.FORWARD_LOW, Direction.PLACE_HIGH})
    intent = Intent(direction=Direction.LEFT_MIDDLE, size=3.0, deadman=True)
    for holds in (False, True):
        shot = shown(window, display, view(available=have, limb_holds=holds, intent=intent))
        assert crossed(shot, Direction.LEFT_MIDDLE, hud.BAD) is holds, holds


def shows(shot: pygame.Surface, drawn: hud.Drawn, fonts: dict[str, pygame.font.Font],
          bg: tuple[int, int, int] = hud.BG) -> bool:
    """Whether the screenshot shows ``drawn``'s text where the HUD says it drew it: the
    pixels there are exactly that text in that font and colour on the background."""
    expected = pygame.Surface(drawn.rect.size)
    expected.fill(bg)
    expected.blit(fonts[drawn.font].render(drawn.text, True, drawn.colour), (0, 0))
    region = shot.subsurface(drawn.rect).convert(expected)
    return pygame.image.tobytes(region, "RGB") == pygame.image.tobytes(expected, "RGB")


def ink_height(shot: pygame.Surface, rect: pygame.Rect) -> int:
    """How tall the letters in ``rect`` are on the screen, in pixels: the rows holding a pixel
    other than the background (the colour of the rect's top left corner, above any
    letter)."""
    region = shot.subsurface(rect)
    ink = pygame.mask.from_threshold(region, region.get_at((0, 0)), (1, 1, 1, 255))
    ink.invert()
    width, height = ink.get_size()
    rows = [y for y in range(height) if any(ink.get_at((x, y)) for x in range(width))]
    return rows[-1] - rows[0] + 1 if rows else 0


@pytest.mark.parametrize(("stage", "code", "words", "colour"), [
    (AckStage.REACHED, "", "pb-1: reached", hud.GOOD),
    (AckStage.MOVING, "", "pb-1: moving", hud.GOOD),
    (AckStage.HOLDING, "", "pb-1: holding", hud.WARN),
    (AckStage.REJECTED, "lease_held", "pb-1: refused: lease_held", hud.BAD),
])
def test_a_screenshot_shows_the_answer_largest_after_the_target(
    window: hud.Hud, display: str, stage: AckStage, code: str, words: str,
    colour: tuple[int, int, int],
) -> None:
    """The robot's answer is on the screen, in its colour, and its letters are taller than
    every other text's but the target's (measured on the screenshot: "pb-1" has a letter
    above and one below the line, so both lines show their font's full height); the target
    is there too."""
    one = view(target=tg.robot("pb-1"), members=["pb-1"],
               robots={"pb-1": state("pb-1", "packbot", "moving")},
               answers={"pb-1": answer("pb-1", 9, stage, code=code, detail="why")})
    shot = shown(window, display, one)
    layout = window.layout
    (said,) = layout["answer"]
    assert said.text.startswith(f"{words}  (") and said.colour == colour
    assert shows(shot, said, window.fonts)
    (target,) = layout["target"]
    assert target.text == "target: pb-1" and shows(shot, target, window.fonts)
    heights = {(role, d.text): ink_height(shot, d.rect) for role, ds in layout.items()
               for d in ds}
    answer_h, target_h = heights["answer", said.text], heights["target", target.text]
    tallest_other = max((h, what) for what, h in heights.items()
                        if what[0] not in ("target", "answer"))
    assert target_h > answer_h > tallest_other[0], (target_h, answer_h, tallest_other)
    assert answer_h >= 1.2 * tallest_other[0], "larger at a glance, not by a pixel"


def test_every_cell_says_its_direction_in_words(window: hud.Hud, display: str) -> None:
    shot = shown(window, display, view(engaged=False))
    layout = window.layout
    for d in Direction:
        (word,) = layout[f"cell:{d.slug}"]
        assert word.text == hud.CELL_WORDS[d.horizontal]
        assert hud.cell_rect(d).contains(word.rect), d
        cell_bg = hud.DIM if d is Direction.LEFT_LOW else hud.CELL_BG
        assert shows(shot, word, window.fonts, cell_bg), d
    assert "crossed out" in " ".join(x.text for x in layout["legend"]).lower()
    for lvl in ("HIGH", "MIDDLE", "LOW"):
        assert lvl in [x.text for x in layout["chart"]]


def test_the_right_half_carries_each_robots_answer_and_link(window: hud.Hud) -> None:
    layout = hud.render(window.screen, view(), window.fonts)
    said = {d.text for d in layout["robot_answer"]}
    assert {"moving", "refused: lease_held"} <= said
    robot_text = [d for d in layout["robot"]]
    assert all(d.rect.left >= hud.RIGHT_X for d in robot_text)
    assert any(d.text.startswith("link ") for d in robot_text), "link health per robot"
    assert any(d.text == "no answer to you yet" for d in layout["robot_answer"])
