"""A virtual X server (Xvfb) for windows a user would look at, and screenshots taken from it.

A screenshot from the X server is what a user would see on a screen: the window's pixels as
the server holds them after the program drew, not the program's own picture of them (a
drawing that never reached the window would not show).
"""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Iterator
from contextlib import contextmanager

import pygame
import pytest
from PIL import ImageGrab

INSTALL = "sudo sh -c 'apt-get update && apt-get install -y xvfb'"
"""How to get Xvfb (``make test`` installs it when it runs as root)."""


@contextmanager
def virtual_display(size: tuple[int, int]) -> Iterator[str]:
    """An Xvfb screen of ``size`` (24-bit colour, no TCP) until the block ends; its display
    name (``:N``). Xvfb picks a free display number and writes it to a pipe once it accepts
    connections, so reading the number is the wait for it to be ready."""
    if shutil.which("Xvfb") is None:
        pytest.fail(f"no Xvfb: install it with {INSTALL} (or run make test as root)")
    read, write = os.pipe()
    proc = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write), "-screen", "0", f"{size[0]}x{size[1]}x24",
         "-nolisten", "tcp"],
        pass_fds=(write,), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    os.close(write)
    try:
        with os.fdopen(read) as ready:
            number = ready.readline().strip()
        if not number.isdigit():
            proc.kill()
            err = proc.communicate(timeout=10)[1].decode(errors="replace")
            pytest.fail(f"Xvfb did not start: {err.strip()[-500:]}")
        yield f":{number}"
    finally:
        proc.terminate()
        proc.wait(timeout=10)
        if proc.stderr is not None:
            proc.stderr.close()


@contextmanager
def sdl_window_on(display: str) -> Iterator[None]:
    """pygame's display on ``display`` through SDL's x11 driver, its window at the screen's
    top left, until the block ends (then the environment is as before and the display is
    closed, so the next pygame user gets the driver it asked for)."""
    wanted = {"DISPLAY": display, "SDL_VIDEODRIVER": "x11", "SDL_VIDEO_WINDOW_POS": "0,0"}
    before = {k: os.environ.get(k) for k in wanted}
    pygame.display.quit()  # a display opened earlier in this process used another driver
    os.environ.update(wanted)
    try:
        pygame.display.init()
        assert pygame.display.get_driver() == "x11", pygame.display.get_driver()
        yield
    finally:
        pygame.display.quit()
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def screenshot(display: str) -> pygame.Surface:
    """The whole screen of ``display`` as the X server holds it (RGB)."""
    image = ImageGrab.grab(xdisplay=display).convert("RGB")
    return pygame.image.frombytes(image.tobytes(), image.size, "RGB")
