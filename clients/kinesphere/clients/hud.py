"""A small pygame window that shows what the robots are about to do, and what they are doing.

Left: the 27 Laban directions as a 3 x 9 chart (rows high / middle / low, columns place and
the 8 horizontals clockwise from forward), each cell a Laban direction symbol shaded by level
as in Laban notation (high striped, middle a dot, low filled); the commanded cell is lit and
directions the selected limb has no poses for are greyed out.
Right: the size as near / mid / far rings with the current reach, the drive vector, deadman
and e-stop state, then one line per robot with its live ``RobotState`` status.

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

from kinesphere.clients.teleop import View  # noqa: E402
from kinesphere.errors import KinesphereError  # noqa: E402
from kinesphere.laban import Direction, Horizontal, Level  # noqa: E402
from kinesphere.protocol import Status  # noqa: E402
from kinesphere.sizes import size_name  # noqa: E402

SIZE = (980, 600)
COLUMNS = (
    Horizontal.PLACE,
    Horizontal.FORWARD,
    Horizontal.RIGHT_FORWARD,
    Horizontal.RIGHT,
    Horizontal.RIGHT_BACK,
    Horizontal.BACK,
    Horizontal.LEFT_BACK,
    Horizontal.LEFT,
    Horizontal.LEFT_FORWARD,
)
ROWS = (Level.HIGH, Level.MIDDLE, Level.LOW)
SHORT = {"place": "P", "forward": "F", "back": "B", "left": "L", "right": "R"}
STALE_S = 0.5

BG = (24, 26, 30)
FG = (225, 228, 232)
DIM = (120, 126, 134)
INK = (235, 235, 235)
UNAVAILABLE = (72, 76, 84)
LIT = (250, 200, 60)
GOOD = (70, 190, 110)
WARN = (235, 160, 50)
BAD = (225, 70, 60)
STATUS_COLOURS: dict[str, tuple[int, int, int]] = {
    Status.MOVING: GOOD,
    Status.HOLDING: (110, 160, 230),
    Status.IDLE: DIM,
    Status.STOPPED: WARN,
    Status.CLAMPED: WARN,
    Status.ESTOP: BAD,
    Status.DATABANK_UNREACHABLE: BAD,
    Status.ERROR: BAD,
}


def _short(h: Horizontal) -> str:
    return "".join(SHORT[w] for w in h.value.split("-"))


def symbol_outline(h: Horizontal, rect: pygame.Rect) -> list[tuple[float, float]]:
    """Polygon of the Laban direction symbol for ``h`` inside ``rect``.

    Place is a rectangle; side directions are wedges pointing that way; forward has a pin on
    top and back a notch below; the diagonals are rectangles cut on the side they point to.
    """
    x0, y0, x1, y1 = rect.left, rect.top, rect.right, rect.bottom
    w, hgt = rect.width, rect.height
    xm = (x0 + x1) / 2
    cut = 0.35 * hgt
    if h is Horizontal.PLACE:
        return [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    if h is Horizontal.LEFT:
        return [(x1, y0), (x1, y1), (x0, (y0 + y1) / 2)]
    if h is Horizontal.RIGHT:
        return [(x0, y0), (x1, (y0 + y1) / 2), (x0, y1)]
    if h is Horizontal.FORWARD:
        pin = 0.18 * w
        top = y0 + cut / 1.5
        return [
            (x0, top),
            (xm - pin, top),
            (xm - pin, y0),
            (xm + pin, y0),
            (xm + pin, top),
            (x1, top),
            (x1, y1),
            (x0, y1),
        ]
    if h is Horizontal.BACK:
        notch = 0.18 * w
        bottom = y1 - cut / 1.5
        return [
            (x0, y0),
            (x1, y0),
            (x1, y1),
            (xm + notch, y1),
            (xm + notch, bottom),
            (xm - notch, bottom),
            (xm - notch, y1),
            (x0, y1),
        ]
    right = "right" in h.value
    forward = "forward" in h.value
    if forward:  # the top is cut, rising towards the side pointed to
        return (
            [(x0, y0), (x1, y0 + cut), (x1, y1), (x0, y1)]
            if not right
            else [(x0, y0 + cut), (x1, y0), (x1, y1), (x0, y1)]
        )
    return (
        [(x0, y0), (x1, y0), (x1, y1 - cut), (x0, y1)]
        if not right
        else [(x0, y0), (x1, y0), (x1, y1), (x0, y1 - cut)]
    )


def draw_symbol(
    surf: pygame.Surface, d: Direction, rect: pygame.Rect, ink: tuple[int, int, int]
) -> None:
    """One direction symbol with Laban's level shading."""
    poly = symbol_outline(d.horizontal, rect)
    if d.level is Level.LOW:
        pygame.draw.polygon(surf, ink, poly)
        return
    if d.level is Level.HIGH:  # diagonal hatching, clipped to the symbol
        mask = pygame.Surface(rect.size, pygame.SRCALPHA)
        local = [(x - rect.left, y - rect.top) for x, y in poly]
        pygame.draw.polygon(mask, (255, 255, 255, 255), local)
        stripes = pygame.Surface(rect.size, pygame.SRCALPHA)
        for k in range(-rect.height, rect.width, 6):
            pygame.draw.line(stripes, (*ink, 255), (k, rect.height), (k + rect.height, 0), 2)
        stripes.blit(mask, (0, 0), special_flags=pygame.BLEND_RGBA_MIN)
        surf.blit(stripes, rect.topleft)
    else:
        cx, cy = rect.center
        pygame.draw.circle(surf, ink, (cx, cy), max(2, rect.width // 8))
    pygame.draw.polygon(surf, ink, poly, 2)


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


def _chart(
    surf: pygame.Surface, fonts: dict[str, pygame.font.Font], view: View, x: int, y: int
) -> None:
    cw, ch = 52, 74
    active = view.intent.direction
    for j, h in enumerate(COLUMNS):
        _text(surf, fonts["small"], _short(h), (x + j * cw + 18, y), DIM)
    for i, lvl in enumerate(ROWS):
        _text(surf, fonts["small"], lvl.value, (x - 56, y + 22 + i * ch + ch // 2 - 8), DIM)
        for j, h in enumerate(COLUMNS):
            d = Direction((h.value, lvl.value))
            cell = pygame.Rect(x + j * cw, y + 20 + i * ch, cw - 4, ch - 4)
            lit = d is active
            if lit:
                pygame.draw.rect(surf, LIT if view.engaged else DIM, cell, border_radius=4)
            if view.asked is d:  # the stick's own choice, replaced by the nearest available
                pygame.draw.rect(surf, LIT, cell, 2, border_radius=4)
            missing = view.available is not None and d not in view.available
            ink = BG if lit else UNAVAILABLE if missing and d is not Direction.PLACE_MIDDLE else INK
            draw_symbol(surf, d, cell.inflate(-18, -16), ink)
    size = view.intent.size
    label = f"{active.slug}   size {size:.2f} ({size_name(size if size > 3 else round(size))})"
    if view.asked is not None:
        label = f"{view.asked.slug} -> {label}"
    _text(surf, fonts["big"], label, (x, y + 20 + 3 * ch + 6), LIT if view.engaged else FG)
    _text(surf, fonts["tiny"], "grey: no pose stored for this limb", (x, y + 20 + 3 * ch + 38), DIM)


def _rings(
    surf: pygame.Surface, fonts: dict[str, pygame.font.Font], view: View, cx: int, cy: int
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


def _drive(
    surf: pygame.Surface, fonts: dict[str, pygame.font.Font], view: View, cx: int, cy: int
) -> None:
    r = 60
    pygame.draw.circle(surf, DIM, (cx, cy), r, 1)
    fwd, left = view.intent.drive_vec
    tip = (cx - left * r, cy - fwd * r)  # screen: up = forward, left = left
    if view.intent.drive is not None:
        colour = LIT if view.engaged else FG
        pygame.draw.line(surf, colour, (cx, cy), tip, 4)
        ang = math.atan2(tip[1] - cy, tip[0] - cx)
        for s in (-1, 1):
            a = ang + math.pi + s * 0.5
            pygame.draw.line(
                surf, colour, tip, (tip[0] + 12 * math.cos(a), tip[1] + 12 * math.sin(a)), 4
            )
        text = f"drive {view.intent.drive.direction} {view.intent.drive.speed:.0%}"
    else:
        pygame.draw.circle(surf, DIM, (cx, cy), 3)
        text = "base still"
    img = fonts["small"].render(text, True, FG)
    surf.blit(
        img, (min(cx - img.get_width() // 2, surf.get_width() - img.get_width() - 4), cy + r + 4)
    )


def _robots(
    surf: pygame.Surface, fonts: dict[str, pygame.font.Font], view: View, x: int, y: int
) -> None:
    y = _text(surf, fonts["mid"], "robots", (x, y), DIM)
    now = time.monotonic()
    if not view.robots:
        _text(surf, fonts["small"], "none heard yet", (x, y), DIM)
    for rid, seen in sorted(view.robots.items()):
        st = seen.state
        stale = now - seen.at > STALE_S
        mark = ">" if view.target.includes(rid) else " "
        status = "silent" if stale else st.status
        colour = DIM if stale else STATUS_COLOURS.get(st.status, FG)
        line = f"{mark} {rid:<12} {st.platform:<8} {status}"
        if st.clamped and not stale:
            line += f" ({', '.join(st.clamped[:3])})"
        y = _text(surf, fonts["small"], line, (x, y), colour)
        if st.detail and not stale and st.status not in (Status.MOVING, Status.IDLE):
            y = _text(surf, fonts["tiny"], f"    {st.detail[:60]}", (x, y), DIM)


def _alias(view: View, label: str) -> str:
    alias = view.aliases.get(label)
    return f"{label} ({alias})" if alias else label


def render(surf: pygame.Surface, view: View, fonts: dict[str, pygame.font.Font]) -> None:
    """Draw the whole HUD for ``view``."""
    surf.fill(BG)
    y = _text(surf, fonts["big"], f"target: {view.target.label}", (16, 10))
    y = _text(
        surf,
        fonts["mid"],
        f"limb {_alias(view, view.limb)}  from  {_alias(view, view.origin)}",
        (16, y),
    )
    src = view.source if view.connected else "DISCONNECTED"
    _text(
        surf,
        fonts["small"],
        f"input: {src}   seq {view.seq}",
        (16, y),
        FG if view.connected else BAD,
    )
    if view.estopped or view.remote_estop:
        who = "this client" if view.estopped else ", ".join(view.remote_estop)
        banner = pygame.Rect(600, 10, 364, 44)
        pygame.draw.rect(surf, BAD, banner, border_radius=6)
        _text(surf, fonts["big"], f"E-STOP ({who})"[:30], (banner.x + 10, banner.y + 8), INK)
    dm = pygame.Rect(600, 60, 364, 34)
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
    _chart(surf, fonts, view, 80, 110)
    _rings(surf, fonts, view, 650, 240)
    _drive(surf, fonts, view, 860, 230)
    _robots(surf, fonts, view, 560, 360)
    if view.catalogue_errors:
        p, msg = next(iter(view.catalogue_errors.items()))
        _text(surf, fonts["small"], f"catalogue {p}: {msg}"[:90], (16, 540), BAD)
    _text(surf, fonts["small"], view.message[:110], (16, 566), FG)


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

    def draw(self, view: View) -> None:
        now = time.monotonic()
        if now - self._last < self.min_dt:
            return
        self._last = now
        render(self.screen, view, self.fonts)
        pygame.display.flip()

    def screenshot(self, path: str | Path) -> None:
        pygame.image.save(self.screen, str(path))
