"""Laban's direction symbols, drawn with pygame: the shape says the horizontal, the shading
the level (high striped, middle a dot, low filled), as in Laban notation."""

from __future__ import annotations

import os

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import pygame  # noqa: E402

from kinesphere.laban import Direction, Horizontal, Level  # noqa: E402


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
