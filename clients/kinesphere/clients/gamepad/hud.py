"""A pygame window that shows what the robots are about to do, and what they answered.

Read from the top left: the **target** (largest), then the **robots' answer** to this
operator's commands (``reached``, ``moving``, ``refused: lease_held``, ``holding``: the
largest thing after the target, in its colour), the limb and origin, the input device. Below,
the 27 Laban directions as three 3 x 3 blocks (high, middle, low), each laid out as seen from
above with the robot facing up: forward is the top row, left the left column, place in the
centre, so the cell that lights is where the stick points. Each cell carries its Laban symbol
(shape = horizontal, shading = level as in Laban notation: high striped, middle a dot, low
filled) and its name in words; a direction the selected limb has no poses for is hatched and
crossed out corner to corner (in red where the stick asks for it). A legend says so. Then the
size as near / mid / far rings and the base drive (an arrow for the velocity, an arc for the
turn).

The right half: the e-stop and deadman banners, what the operator must know now (nobody hears
the target, a lease held by another), and one card per robot: its answer to this operator, its
status in the operator's words (:mod:`kinesphere.clients.report`), its link's health (how old
its last state is), odometry and lease; wrapped, never cut off.

:func:`render` draws onto any surface and returns where each text went (:data:`Layout`), so a
test can check a screenshot against what should be on it; :class:`Hud` owns the window.
"""

from __future__ import annotations

import math
import os
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import pygame  # noqa: E402

from kinesphere.clients.gamepad.drive import Steering  # noqa: E402
from kinesphere.clients.gamepad.readout import Readout  # noqa: E402
from kinesphere.clients.gamepad.state import Action  # noqa: E402
from kinesphere.clients.gamepad.symbols import draw_symbol  # noqa: E402
from kinesphere.clients.report import (  # noqa: E402
    Line,
    answer_headline,
    answer_words,
    robot_lines,
)
from kinesphere.errors import KinesphereError  # noqa: E402
from kinesphere.hints import status as status_hint  # noqa: E402
from kinesphere.laban import Direction, Horizontal, Level  # noqa: E402
from kinesphere.sizes import size_name  # noqa: E402

SIZE = (1100, 720)
BLOCK = (
    (Horizontal.LEFT_FORWARD, Horizontal.FORWARD, Horizontal.RIGHT_FORWARD),
    (Horizontal.LEFT, Horizontal.PLACE, Horizontal.RIGHT),
    (Horizontal.LEFT_BACK, Horizontal.BACK, Horizontal.RIGHT_BACK),
)
"""One level's 9 horizontals as seen from above, robot facing up (rows top to bottom)."""
LEVELS = (Level.HIGH, Level.MIDDLE, Level.LOW)
"""The blocks, left to right."""
CELL_WORDS = {
    Horizontal.PLACE: "place", Horizontal.FORWARD: "fwd", Horizontal.BACK: "back",
    Horizontal.LEFT: "left", Horizontal.RIGHT: "right", Horizontal.LEFT_FORWARD: "L-fwd",
    Horizontal.RIGHT_FORWARD: "R-fwd", Horizontal.LEFT_BACK: "L-back",
    Horizontal.RIGHT_BACK: "R-back",
}
"""The word under each cell's symbol (the block's heading says the level)."""
LEFT_X = 16
LEFT_W = 620
RIGHT_X = 660
RIGHT_W = SIZE[0] - RIGHT_X - 16
CHART = (LEFT_X, 200)
"""Top-left corner of the first block's first cell."""
CELL = 58
BLOCK_STEP = 3 * CELL + 20
RINGS = (116, 580)
DRIVE = (420, 565)

BG = (24, 26, 30)
FG = (225, 228, 232)
DIM = (120, 126, 134)
INK = (235, 235, 235)
CELL_BG = (44, 48, 56)
UNAVAILABLE_BG = (30, 30, 34)
UNAVAILABLE = (150, 90, 90)
"""The cross over a direction the limb has no pose for."""
LIT = (250, 200, 60)
GOOD = (70, 190, 110)
WARN = (235, 160, 50)
BAD = (225, 70, 60)
INFO = (110, 160, 230)
TONES = {"ok": GOOD, "info": INFO, "warn": WARN, "bad": BAD, "dim": DIM}
TONE_RANK = {"dim": 0, "info": 1, "ok": 2, "warn": 3, "bad": 4}
"""Which tone a line about several robots takes: the most alarming of theirs."""
FONT_SIZES = {"tiny": 17, "small": 21, "mid": 25, "big": 29, "answer": 36, "target": 42}
"""Text sizes in pixels: the target largest, then the robots' answer, then everything else."""


@dataclass(frozen=True)
class Drawn:
    """A piece of text the HUD drew: where, what, and in which font."""

    rect: pygame.Rect
    text: str
    font: str
    colour: tuple[int, int, int]


Layout = dict[str, list[Drawn]]
"""What :func:`render` drew, by role (``target``, ``answer``, ``notice``, ``robot``...)."""


def cell_rect(d: Direction) -> pygame.Rect:
    """Where the chart draws ``d``."""
    b = LEVELS.index(d.level)
    row = next(i for i, r in enumerate(BLOCK) if d.horizontal in r)
    col = BLOCK[row].index(d.horizontal)
    x = CHART[0] + b * BLOCK_STEP + col * CELL
    return pygame.Rect(x, CHART[1] + row * CELL, CELL - 4, CELL - 4)


class _Pen:
    """Draws text on a surface and remembers where (the :data:`Layout`)."""

    def __init__(self, surf: pygame.Surface, fonts: dict[str, pygame.font.Font]) -> None:
        self.surf = surf
        self.fonts = fonts
        self.layout: Layout = {}

    def text(self, role: str, font: str, text: str, pos: tuple[int, int],
             colour: tuple[int, int, int] = FG) -> int:
        """One line; returns the y below it."""
        img = self.fonts[font].render(text, True, colour)
        rect = self.surf.blit(img, pos)
        self.layout.setdefault(role, []).append(Drawn(rect, text, font, colour))
        return pos[1] + img.get_height() + 2

    def paragraph(self, role: str, font: str, text: str, x: int, y: int, width: int,
                  colour: tuple[int, int, int] = FG, indent: int = 0) -> int:
        """``text`` wrapped to ``width`` (later lines indented); returns the next y."""
        for i, line in enumerate(wrap(self.fonts[font], text, width - indent)):
            y = self.text(role, font, line, (x + (indent if i else 0), y), colour)
        return y

    def height(self, font: str, text: str, width: int) -> int:
        """The height :meth:`paragraph` would take."""
        f = self.fonts[font]
        return len(wrap(f, text, width)) * (f.get_linesize() + 2)


def wrap(font: pygame.font.Font, text: str, width: int) -> list[str]:
    """``text`` broken at spaces into lines no wider than ``width`` (long words are split)."""
    lines: list[str] = []
    current = ""
    for word in text.split(" "):
        candidate = f"{current} {word}" if current else word
        if font.size(candidate)[0] <= width:
            current = candidate
            continue
        if current:
            lines.append(current)
        while font.size(word)[0] > width and len(word) > 1:
            cut = len(word)
            while cut > 1 and font.size(word[:cut])[0] > width:
                cut -= 1
            lines.append(word[:cut])
            word = word[cut:]
        current = word
    lines.append(current)
    return lines


def _cross(surf: pygame.Surface, rect: pygame.Rect, colour: tuple[int, int, int]) -> None:
    """Crossed out corner to corner, thick, over hatching: nothing else in the chart looks
    like it."""
    for k in range(-rect.height, rect.width, 7):
        a = (rect.left + max(0, k), rect.bottom - max(0, -k))
        b = (rect.left + min(rect.width, k + rect.height), rect.top + max(0, k + rect.height
                                                                           - rect.width))
        pygame.draw.line(surf, (52, 40, 40), a, b, 1)
    pygame.draw.line(surf, colour, rect.topleft, rect.bottomright, 5)
    pygame.draw.line(surf, colour, rect.topright, rect.bottomleft, 5)


def _chart(pen: _Pen, view: Readout) -> None:
    surf = pen.surf
    active = view.intent.direction
    x0, y0 = CHART
    for b, lvl in enumerate(LEVELS):
        pen.text("chart", "mid", lvl.value.upper(), (x0 + b * BLOCK_STEP, y0 - 28), DIM)
    for d in Direction:
        cell = cell_rect(d)
        lit = d is active
        missing = view.available is not None and d not in view.available
        missing = missing and d is not Direction.PLACE_MIDDLE
        if lit:
            bg = LIT if view.engaged and not view.stick_holds else DIM
        else:
            bg = UNAVAILABLE_BG if missing else CELL_BG
        pygame.draw.rect(surf, bg, cell, border_radius=4)
        if view.asked is d:  # the stick's own choice, replaced by the nearest available
            pygame.draw.rect(surf, LIT, cell, 3, border_radius=4)
        ink = BG if lit else DIM if missing else INK
        draw_symbol(surf, d, pygame.Rect(cell.x + 13, cell.y + 5, cell.w - 26, cell.h - 24), ink)
        word = CELL_WORDS[d.horizontal]
        width = pen.fonts["tiny"].size(word)[0]
        pen.text(f"cell:{d.slug}", "tiny", word, (cell.centerx - width // 2, cell.bottom - 17),
                 ink)
        if missing:
            refused = view.asked is d or (lit and view.limb_holds)
            _cross(surf, cell.inflate(-6, -6), BAD if refused else UNAVAILABLE)
    size = view.intent.size
    if view.stick_holds:
        label = "stick centred: the limb holds its pose"
    elif view.limb_holds:
        label = f"{active.slug}: no pose near it, the limb holds (driving still works)"
    else:
        label = f"{active.slug}   size {size:.2f} ({size_name(size if size > 3 else round(size))})"
        if view.asked is not None:
            label = f"{view.asked.slug} -> {label}"
    y = y0 + 3 * CELL + 6
    y = pen.text("direction", "big", label, (x0, y), LIT if view.engaged else FG)
    pen.paragraph("legend", "tiny", "symbol shape = direction seen from above (robot facing "
                  "up), shading = level: striped high, dot middle, filled low. Crossed out: "
                  "the limb has no pose there; a push there is served by the nearest stored "
                  "direction on the same side. After a push, the stick back in the centre = "
                  "the limb's neutral pose.", x0, y, LEFT_W, DIM)


def _rings(pen: _Pen, view: Readout, cx: int, cy: int) -> None:
    surf = pen.surf
    r0 = 24
    for k, name in enumerate(("near", "mid", "far"), start=1):
        pygame.draw.circle(surf, DIM, (cx, cy), r0 * k, 1)
        img = pen.fonts["tiny"].render(name, True, DIM)
        surf.blit(img, (cx - img.get_width() // 2, cy + r0 * k - img.get_height() - 2))
    size = view.intent.size
    if size > 0:
        colour = LIT if view.engaged else FG
        pygame.draw.circle(surf, colour, (cx, cy), max(2, int(r0 * min(size, 3.0))), 3)
        if size > 3.0:
            for a in range(0, 360, 20):
                t = math.radians(a)
                rr = r0 * 3 + 6 + 4 * (size - 3.0)
                pygame.draw.circle(surf, BAD, (cx + rr * math.cos(t), cy + rr * math.sin(t)), 2)
    pen.text("chart", "small", "size", (cx - r0 * 3, cy - r0 * 3 - 20), DIM)


def _arrowhead(surf: pygame.Surface, colour: tuple[int, int, int], tip: tuple[float, float],
               ang: float) -> None:
    for s in (-1, 1):
        a = ang + math.pi + s * 0.5
        end = (tip[0] + 12 * math.cos(a), tip[1] + 12 * math.sin(a))
        pygame.draw.line(surf, colour, tip, end, 4)


STEERING_WORDS = {
    Steering.NONE: "fixed base: the left stick does nothing",
    Steering.HOLONOMIC: "holonomic: stick = velocity, d-pad left/right turns",
    Steering.ARCADE: "tracks/wheels: stick up/down drives, left/right turns",
}


def _drive(pen: _Pen, view: Readout, cx: int, cy: int) -> None:
    surf = pen.surf
    r = 56
    pygame.draw.circle(surf, DIM, (cx, cy), r, 1)
    drive = view.intent.drive
    colour = LIT if view.engaged else FG
    if drive is not None and (drive.forward or drive.left):
        tip = (cx - drive.left * r, cy - drive.forward * r)  # screen: up = forward
        pygame.draw.line(surf, colour, (cx, cy), tip, 4)
        _arrowhead(surf, colour, tip, math.atan2(tip[1] - cy, tip[0] - cx))
    else:
        pygame.draw.circle(surf, DIM, (cx, cy), 3)
    if drive is not None and drive.yaw:
        # an arc above the robot, sweeping the way it turns (positive = counter-clockwise)
        sweep = math.pi * 0.8 * abs(drive.yaw)
        start = math.pi / 2
        end = start + sweep if drive.yaw > 0 else start - sweep
        rect = pygame.Rect(cx - r - 10, cy - r - 10, 2 * r + 20, 2 * r + 20)
        lo, hi = min(start, end), max(start, end)
        pygame.draw.arc(surf, colour, rect, lo, hi, 4)
        tip = (cx + (r + 10) * math.cos(end), cy - (r + 10) * math.sin(end))
        _arrowhead(surf, colour, tip, -end - (math.pi / 2 if drive.yaw > 0 else -math.pi / 2))
    if drive is None:
        text = "base still"
    else:
        text = (f"forward {drive.forward:+.0%}  left {drive.left:+.0%}  "
                f"turn {drive.yaw:+.0%}")
    if view.intent.turbo:
        text += "  TURBO"
    y = pen.text("drive", "small", text, (cx - 190, cy + r + 12), FG)
    pen.text("drive", "tiny", STEERING_WORDS[view.intent.steering], (cx - 190, y), DIM)


def answer_summary(view: Readout) -> Line:
    """The robots' answer to this operator, for the line under the target: one robot's
    headline (``yb-1: reached``), or a count per headline for several (``2 reached, 1
    refused: lease_held``); that nobody answers when nobody is heard."""
    if view.unheard:
        return Line("nobody answers: no robot heard", "bad")
    now = time.monotonic()
    answered = {rid: view.answers[rid] for rid in view.members if rid in view.answers}
    if not answered:
        press = view.presses.get(Action.DEADMAN, "")
        how = f": hold {press} and push the stick" if press else ""
        return Line(f"no answer yet{how}", "dim")
    heads = {rid: answer_headline(a.ack) for rid, a in answered.items()}
    if len(answered) == 1 and len(view.members) == 1:
        (rid, a), = answered.items()
        return Line(f"{rid}: {heads[rid].text}  ({now - a.at:.1f} s ago)", heads[rid].tone)
    counts = Counter(h.text for h in heads.values())
    worst = max(heads.values(), key=lambda h: TONE_RANK.get(h.tone, 0))
    silent = len(view.members) - len(answered)
    words = [f"{n} {text}" for text, n in counts.most_common()]
    if silent:
        words.append(f"{silent} no answer yet")
    return Line(", ".join(words), worst.tone)


def _robots(pen: _Pen, view: Readout, top: int) -> None:
    """One card per robot in the right half: its answer, status, link health; robots that do
    not fit are counted."""
    x, width, bottom = RIGHT_X, RIGHT_W, SIZE[1] - 8
    y = pen.text("robots", "small", "robots  (> = targeted)", (x, top), DIM)
    now = time.monotonic()
    if not view.robots:
        pen.paragraph("robots", "small", "none heard: no robot state has arrived", x, y,
                      width, DIM)
        return
    shown = 0
    entries = sorted(view.robots.items(), key=lambda kv: (
        not view.target.includes(kv[0], kv[1].state.groups), kv[0]))
    for rid, seen in entries:
        st = seen.state
        targeted = view.target.includes(rid, st.groups)
        answer = view.answers.get(rid)
        age = now - seen.at
        lines = robot_lines(st, age, view.sender, view.presses.get(Action.RELEASE, ""))
        head = (answer_headline(answer.ack) if answer is not None
                else Line("no answer to you yet", "dim"))
        rest = [answer_words(answer.ack, now - answer.at)] if answer is not None else []
        rest += lines
        need = 30 + sum(pen.height("small", ln.text, width - 16) for ln in rest)
        if y + need > bottom - 20:
            break
        mark = "> " if targeted else "  "
        title = f"{mark}{rid} ({st.platform})"
        pen.text("robot", "mid", title, (x, y), FG if targeted else DIM)
        hx = x + pen.fonts["mid"].size(title + "   ")[0]
        y = pen.text("robot_answer", "mid", head.text, (hx, y), TONES.get(head.tone, FG))
        for ln in rest:
            y = pen.paragraph("robot", "small", ln.text, x + 16, y, width - 16,
                              TONES.get(ln.tone, FG))
        y += 6
        shown += 1
    if shown < len(entries):
        pen.text("robots", "small", f"... and {len(entries) - shown} more ('{status_hint()}')",
                 (x, bottom - 20), WARN)


def _alias(view: Readout, label: str) -> str:
    alias = view.aliases.get(label)
    return f"{label} ({alias})" if alias else label


def _banners(pen: _Pen, view: Readout) -> int:
    """The e-stop and deadman banners at the top of the right half; returns the y below."""
    surf, x, w = pen.surf, RIGHT_X, RIGHT_W
    y = 10
    if view.estopped or view.remote_estop:
        who = "by you" if view.estopped else ", ".join(view.remote_estop)
        banner = pygame.Rect(x, y, w, 44)
        pygame.draw.rect(surf, BAD, banner, border_radius=6)
        lines = wrap(pen.fonts["big"], f"E-STOP ({who})", w - 20)
        pen.text("estop", "big", lines[0] + (" ..." if len(lines) > 1 else ""),
                 (banner.x + 10, banner.y + 8), INK)
        y = banner.bottom + 6
    dm = pygame.Rect(x, y, w, 34)
    if not view.deadman_required:
        colour, text = WARN, "deadman OFF (--no-deadman)"
    elif view.engaged and view.unheard:
        colour, text = BAD, "deadman held: streaming to NOBODY"
    elif view.engaged:
        colour, text = GOOD, "deadman held: streaming"
    elif view.need_fresh_deadman:
        colour, text = WARN, "let go of the deadman, then press it"
    elif view.intent.deadman:
        colour, text = WARN, "deadman held: not streaming"
    else:
        press = view.presses.get(Action.DEADMAN, "")
        colour, text = DIM, "deadman released: robots hold" + (
            f" (hold {press})" if press else "")
    pygame.draw.rect(surf, colour, dm, border_radius=6)
    pen.text("deadman", "mid", text, (dm.x + 10, dm.y + 6), BG)
    return dm.bottom + 8


def render(surf: pygame.Surface, view: Readout, fonts: dict[str, pygame.font.Font]) -> Layout:
    """Draw the whole HUD for ``view``; returns where each piece of text went."""
    surf.fill(BG)
    pen = _Pen(surf, fonts)
    target = view.target.label
    if view.target.kind != "robot":
        target += f" ({', '.join(view.members) or 'nobody heard'})"
    y = pen.paragraph("target", "target", f"target: {target}", LEFT_X, 8, LEFT_W,
                      BAD if view.unheard else FG)
    answer = answer_summary(view)
    y = pen.paragraph("answer", "answer", answer.text, LEFT_X, y + 2, LEFT_W,
                      TONES.get(answer.tone, FG))
    y = pen.text("limb", "mid", f"limb {_alias(view, view.limb)}  from  "
                 f"{_alias(view, view.origin)}", (LEFT_X, y + 2))
    src = (f"input: {view.input_name or view.source}" if view.connected
           else "DISCONNECTED: plug a controller in")
    pen.text("input", "small", f"{src}   you: {view.sender}   seq {view.seq}", (LEFT_X, y),
             FG if view.connected else BAD)
    _chart(pen, view)
    _rings(pen, view, *RINGS)
    _drive(pen, view, *DRIVE)
    y = _banners(pen, view)
    if view.notice:
        y = pen.paragraph("notice", "small", view.notice, RIGHT_X, y, RIGHT_W, BAD)
    if view.message:
        y = pen.paragraph("message", "small", view.message, RIGHT_X, y, RIGHT_W, LIT)
    for p, msg in list(view.catalogue_errors.items())[:1]:
        y = pen.paragraph("notice", "small", f"catalogue of {p}: {msg}", RIGHT_X, y, RIGHT_W,
                          BAD)
    _robots(pen, view, y + 4)
    return pen.layout


def load_fonts() -> dict[str, pygame.font.Font]:
    pygame.font.init()
    return {name: pygame.font.Font(None, px) for name, px in FONT_SIZES.items()}


class Hud:
    """The HUD window; :meth:`draw` at most ``fps`` times a second."""

    def __init__(self, size: tuple[int, int] = SIZE, fps: float = 30.0) -> None:
        try:
            self.screen = pygame.display.set_mode(size)
        except pygame.error as exc:
            raise KinesphereError(
                "unavailable", f"cannot open the HUD window ({exc}); use --headless"
            ) from None
        pygame.display.set_caption("kinesphere gamepad")
        self.fonts = load_fonts()
        self.min_dt = 1.0 / fps
        self._last = 0.0
        self.layout: Layout = {}
        """Where the last frame put each text."""

    def draw(self, view: Readout) -> None:
        now = time.monotonic()
        if now - self._last < self.min_dt:
            return
        self._last = now
        self.layout = render(self.screen, view, self.fonts)
        pygame.display.flip()

    def screenshot(self, path: str | Path) -> None:
        pygame.image.save(self.screen, str(path))
