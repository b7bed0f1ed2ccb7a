"""A pygame window that shows what the robots are about to do, and what they are doing.

Left: the 27 Laban directions as three 3 x 3 blocks (high, middle, low), each laid out as
seen from above with the robot facing up: forward is the top row, left the left column, place
in the centre. So the cell that lights is where the stick points. Each cell is a Laban
direction symbol shaded by level as in Laban notation (high striped, middle a dot, low
filled); a direction the selected limb has no poses for is crossed out on a dark cell.
Right: the size as near / mid / far rings, and the base drive (an arrow for the velocity, an
arc for the turn). Below: every robot in the operator's words (:mod:`kinesphere.clients.report`):
status, odometry, link age, control lease, wrapped, never cut off.

:func:`render` draws onto any surface (tests use SDL's dummy driver and save a PNG);
:class:`Hud` owns the window.
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import pygame  # noqa: E402

from kinesphere.clients.gamepad.drive import Steering  # noqa: E402
from kinesphere.clients.gamepad.readout import Readout  # noqa: E402
from kinesphere.clients.gamepad.symbols import draw_symbol  # noqa: E402
from kinesphere.clients.report import Line, robot_lines  # noqa: E402
from kinesphere.errors import KinesphereError  # noqa: E402
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
CHART = (70, 150)
"""Top-left corner of the first block's first cell."""
MESSAGES_Y = 346
"""Where the notice and the last message go, under the chart."""
ROBOTS_Y = 400
CELL = 46
BLOCK_STEP = 3 * CELL + 24

BG = (24, 26, 30)
FG = (225, 228, 232)
DIM = (120, 126, 134)
INK = (235, 235, 235)
CELL_BG = (44, 48, 56)
UNAVAILABLE_BG = (30, 30, 34)
UNAVAILABLE = (88, 60, 60)
LIT = (250, 200, 60)
GOOD = (70, 190, 110)
WARN = (235, 160, 50)
BAD = (225, 70, 60)
INFO = (110, 160, 230)
TONES = {"ok": GOOD, "info": INFO, "warn": WARN, "bad": BAD, "dim": DIM}


def cell_rect(d: Direction) -> pygame.Rect:
    """Where the chart draws ``d``."""
    b = LEVELS.index(d.level)
    row = next(i for i, r in enumerate(BLOCK) if d.horizontal in r)
    col = BLOCK[row].index(d.horizontal)
    x = CHART[0] + b * BLOCK_STEP + col * CELL
    return pygame.Rect(x, CHART[1] + row * CELL, CELL - 4, CELL - 4)


def _text(
    surf: pygame.Surface,
    font: pygame.font.Font,
    text: str,
    pos: tuple[int, int],
    colour: tuple[int, int, int] = FG,
) -> int:
    img = font.render(text, True, colour)
    surf.blit(img, pos)
    return pos[1] + img.get_height() + 2


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


def _paragraph(
    surf: pygame.Surface, font: pygame.font.Font, text: str, x: int, y: int, width: int,
    colour: tuple[int, int, int] = FG, indent: int = 0,
) -> int:
    """Draw ``text`` wrapped to ``width``; later lines indented; returns the next y."""
    for i, line in enumerate(wrap(font, text, width - indent)):
        y = _text(surf, font, line, (x + (indent if i else 0), y), colour)
    return y


def _cross(surf: pygame.Surface, rect: pygame.Rect, colour: tuple[int, int, int]) -> None:
    pygame.draw.line(surf, colour, rect.topleft, rect.bottomright, 3)
    pygame.draw.line(surf, colour, rect.topright, rect.bottomleft, 3)


def _chart(surf: pygame.Surface, fonts: dict[str, pygame.font.Font], view: Readout) -> None:
    active = view.intent.direction
    x0, y0 = CHART
    for b, lvl in enumerate(LEVELS):
        _text(surf, fonts["mid"], lvl.value.upper(), (x0 + b * BLOCK_STEP, y0 - 24), DIM)
    _text(surf, fonts["tiny"], "seen from above, robot facing up: stick up = forward row, "
          "stick left = left column", (x0, y0 - 44), DIM)
    for d in Direction:
        cell = cell_rect(d)
        lit = d is active
        missing = view.available is not None and d not in view.available
        missing = missing and d is not Direction.PLACE_MIDDLE
        if lit:
            bg = LIT if view.engaged else DIM
        else:
            bg = UNAVAILABLE_BG if missing else CELL_BG
        pygame.draw.rect(surf, bg, cell, border_radius=4)
        if view.asked is d:  # the stick's own choice, replaced by the nearest available
            pygame.draw.rect(surf, LIT, cell, 3, border_radius=4)
        ink = BG if lit else UNAVAILABLE if missing else INK
        draw_symbol(surf, d, cell.inflate(-16, -12), ink)
        if missing:
            refused = view.asked is d or (lit and view.limb_holds)
            _cross(surf, cell.inflate(-8, -8), BAD if refused else UNAVAILABLE)
    size = view.intent.size
    label = f"{active.slug}   size {size:.2f} ({size_name(size if size > 3 else round(size))})"
    if view.asked is not None:
        label = f"{view.asked.slug} -> {label}"
    if view.limb_holds:
        label = f"{active.slug}: no pose near it, the limb holds (driving still works)"
    y = y0 + 3 * CELL + 8
    y = _text(surf, fonts["big"], label, (x0, y), LIT if view.engaged else FG)
    _text(surf, fonts["tiny"], "crossed out: no pose stored for this limb; a push there is "
          "served by the nearest stored direction on the same side", (x0, y), DIM)


def _rings(
    surf: pygame.Surface, fonts: dict[str, pygame.font.Font], view: Readout, cx: int, cy: int
) -> None:
    r0 = 26
    for k, name in enumerate(("near", "mid", "far"), start=1):
        pygame.draw.circle(surf, DIM, (cx, cy), r0 * k, 1)
        img = fonts["tiny"].render(name, True, DIM)
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
    _text(surf, fonts["small"], "size", (cx - r0 * 3, cy - r0 * 3 - 18), DIM)


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


def _drive(
    surf: pygame.Surface, fonts: dict[str, pygame.font.Font], view: Readout, cx: int, cy: int
) -> None:
    r = 60
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
    y = _text(surf, fonts["small"], text, (cx - 110, cy + r + 14), FG)
    _text(surf, fonts["tiny"], STEERING_WORDS[view.intent.steering], (cx - 110, y), DIM)


def _robots(surf: pygame.Surface, fonts: dict[str, pygame.font.Font], view: Readout, top: int
            ) -> None:
    """Every robot, wrapped, in one or two columns; robots that do not fit are counted."""
    x, width, bottom = 16, surf.get_width() - 32, surf.get_height() - 8
    y = _text(surf, fonts["mid"], "robots  (> = targeted)", (x, top), DIM)
    now = time.monotonic()
    if not view.robots:
        _text(surf, fonts["small"], "none heard yet: no robot state has arrived", (x, y), DIM)
        return
    entries: list[tuple[str, list[Line], bool]] = []
    for rid, seen in sorted(view.robots.items()):
        st = seen.state
        answer = view.answers.get(rid)
        lines = robot_lines(st, now - seen.at, view.sender,
                            answer=answer.ack if answer else None,
                            answer_age_s=now - answer.at if answer else 0.0)
        entries.append((f"{rid}  ({st.platform})", lines, view.target.includes(rid, st.groups)))
    columns = 1 if len(entries) <= 3 else 2
    col_w = width // columns - 12
    per_col = -(-len(entries) // columns)
    start_y = y
    shown = 0
    for i, (title, lines, targeted) in enumerate(entries):
        col = i // per_col
        if i % per_col == 0:
            y = start_y
        cx = x + col * (col_w + 24)
        need = 22 + sum(len(wrap(fonts["small"], ln.text, col_w - 16)) * 20 for ln in lines)
        if y + need > bottom:
            continue
        mark = "> " if targeted else "  "
        y = _text(surf, fonts["mid"], mark + title, (cx, y), FG if targeted else DIM)
        for ln in lines:
            for part in wrap(fonts["small"], ln.text, col_w - 16):
                y = _text(surf, fonts["small"], part, (cx + 16, y), TONES.get(ln.tone, FG))
        y += 4
        shown += 1
    if shown < len(entries):
        _text(surf, fonts["small"], f"... and {len(entries) - shown} more (kinesphere status)",
              (x + width - 300, bottom - 18), WARN)


def _alias(view: Readout, label: str) -> str:
    alias = view.aliases.get(label)
    return f"{label} ({alias})" if alias else label


def _banners(surf: pygame.Surface, fonts: dict[str, pygame.font.Font], view: Readout) -> None:
    x, w = 700, 384
    if view.estopped or view.remote_estop:
        who = "by you" if view.estopped else ", ".join(view.remote_estop)
        banner = pygame.Rect(x, 10, w, 44)
        pygame.draw.rect(surf, BAD, banner, border_radius=6)
        lines = wrap(fonts["big"], f"E-STOP ({who})", w - 20)
        _text(surf, fonts["big"], lines[0] + (" ..." if len(lines) > 1 else ""),
              (banner.x + 10, banner.y + 8), INK)
    dm = pygame.Rect(x, 60, w, 34)
    if not view.deadman_required:
        colour, text = WARN, "deadman OFF (--no-deadman)"
    elif view.engaged:
        colour, text = GOOD, "deadman held: streaming"
    elif view.need_fresh_deadman:
        colour, text = WARN, "let go of the deadman, then press it"
    elif view.intent.deadman:
        colour, text = WARN, "deadman held: not streaming"
    else:
        colour, text = DIM, "deadman released: robots hold"
    pygame.draw.rect(surf, colour, dm, border_radius=6)
    _text(surf, fonts["mid"], text, (dm.x + 10, dm.y + 7), BG)


def render(surf: pygame.Surface, view: Readout, fonts: dict[str, pygame.font.Font]) -> None:
    """Draw the whole HUD for ``view``."""
    surf.fill(BG)
    width = 670
    target = view.target.label
    if view.target.kind != "robot":
        target += f" ({', '.join(view.members) or 'nobody heard yet'})"
    y = _paragraph(surf, fonts["big"], f"target: {target}", 16, 10, width)
    y = _text(surf, fonts["mid"],
              f"limb {_alias(view, view.limb)}  from  {_alias(view, view.origin)}", (16, y))
    src = view.source if view.connected else "DISCONNECTED: plug a controller in"
    y = _text(surf, fonts["small"], f"input: {src}   you: {view.sender}   seq {view.seq}",
              (16, y), FG if view.connected else BAD)
    _banners(surf, fonts, view)
    y = MESSAGES_Y
    if view.notice:
        y = _paragraph(surf, fonts["small"], view.notice, 16, y, 1060, BAD)
    if view.message:
        y = _paragraph(surf, fonts["small"], view.message, 16, y, 1060, LIT)
    for p, msg in list(view.catalogue_errors.items())[:1]:
        y = _paragraph(surf, fonts["small"], f"catalogue of {p}: {msg}", 16, y, 1060, BAD)
    _chart(surf, fonts, view)
    _rings(surf, fonts, view, 640, 230)
    _drive(surf, fonts, view, 900, 230)
    _robots(surf, fonts, view, max(y + 6, ROBOTS_Y))


def load_fonts() -> dict[str, pygame.font.Font]:
    pygame.font.init()
    return {
        "tiny": pygame.font.Font(None, 18),
        "small": pygame.font.Font(None, 22),
        "mid": pygame.font.Font(None, 26),
        "big": pygame.font.Font(None, 32),
    }


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

    def draw(self, view: Readout) -> None:
        now = time.monotonic()
        if now - self._last < self.min_dt:
            return
        self._last = now
        render(self.screen, view, self.fonts)
        pygame.display.flip()

    def screenshot(self, path: str | Path) -> None:
        pygame.image.save(self.screen, str(path))
