"""Headless Chromium for the view tests: Debian's ``chromium`` driven by Playwright.

Not a test module. The browser is Debian's (``make test`` installs it when missing and run as
root); Playwright's own browser download is not used. A missing browser fails the test with
the command that installs it, never a skip.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from support.wait import WAIT_S

CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
INSTALL = "apt-get update && apt-get install -y chromium"


def chromium() -> str:
    """The browser's path, or a failure naming the install command."""
    path = CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium")
    if path is None:
        pytest.fail(f"the view test needs Debian's chromium: run `{INSTALL}` as root "
                    "(make test does it for you when run as root)")
    return path


@contextmanager
def browser_page(width: int = 1280, height: int = 720) -> Iterator[Any]:
    """A page in a fresh headless Chromium profile. Its actions (a screenshot, a click, a wait
    for text) wait as long as every other wait of the tests, not Playwright's 30 s: on a loaded
    machine the software-rendered canvas can take longer to give a frame."""
    from playwright.sync_api import sync_playwright

    exe = chromium()
    with tempfile.TemporaryDirectory(prefix="kinesphere-chromium-") as profile, \
            sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            profile, executable_path=exe, args=FLAGS, headless=True,
            viewport={"width": width, "height": height})
        try:
            page = context.new_page()
            page.set_default_timeout(WAIT_S * 1000)
            yield page
        finally:
            context.close()


def pixels(png: bytes) -> npt.NDArray[np.int16]:
    """An RGB screenshot as an ``(h, w, 3)`` array."""
    import io

    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.int16)


def coloured(image: npt.NDArray[np.int16], threshold: int = 60) -> npt.NDArray[np.bool_]:
    """Saturated pixels: the robots' painted links (background, grid and text are grey)."""
    spread: npt.NDArray[np.int16] = image.max(axis=2) - image.min(axis=2)
    return spread > threshold
