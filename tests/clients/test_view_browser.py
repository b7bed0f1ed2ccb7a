"""``kinesphere view`` in headless Chromium: robots appear with their liveliness, and move.

A router (the hub), a databank, a Baxter and a youBot agent and the view run as processes on
loopback; Debian's Chromium opens the page. The command goes through the router as a client:
a peer's put could reach only the view's wildcard subscriber while its direct link to the
agent is still forming, and ``send`` would report it sent. Baxter is started first so it
takes the left slot and the youBot the right one. The test waits until the page lists both
robots and both halves of the 3D canvas show a robot's coloured links, takes a screenshot,
moves Baxter's right arm (away from the youBot) with ``kinesphere send``, waits until the
agent reports it reached the pose, and checks that Baxter's half of the canvas changed while
the youBot's stayed as it was.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest

from kinesphere.procs import Supervisor
from kinesphere.zconfig import free_port
from support.system import Observer, at_pose, log_folder, query_pose, router_hub
from support.view import browser_page, coloured, pixels
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

POSE = ("limb_11", "distal_11", "right-high", 3)
AGENT_HZ = "250"



def canvas_shot(page: Any) -> np.ndarray:
    return pixels(page.locator("canvas").first.screenshot())


def halves(mask: np.ndarray) -> tuple[int, int]:
    """Counts of ``mask`` in the left and right half (the gizmo corner left out)."""
    h, w = mask.shape
    m = mask.copy()
    m[int(h * 0.8):, : int(w * 0.12)] = False  # the axes gizmo, bottom left
    return int(m[:, : w // 2].sum()), int(m[:, w // 2:].sum())


def test_view_draws_and_moves_robots(sup: Supervisor) -> None:
    endpoint = router_hub(sup)  # the hub: it routes every put
    web = free_port()
    sup.spawn("databank", ["databank", "serve", "--connect", endpoint, "--platform", "baxter",
                           "--platform", "youbot"])
    obs = Observer(mode="peer", connect=[endpoint])
    try:
        obs.wait_alive(set(), databank=True, sup=sup)
        sup.spawn("view", ["view", "--connect", endpoint, "--port", str(web)])
        with browser_page() as page:
            until(lambda: _loads(page, f"http://127.0.0.1:{web}/"), WAIT_S, "the view's page",
                  guard=sup.check)
            page.get_by_text("0 robot(s)").wait_for(timeout=WAIT_S * 1000)
            for rid, platform in (("baxter-1", "baxter"), ("youbot-1", "youbot")):
                sup.spawn(rid, ["agent", platform, "--id", rid, "--connect", endpoint,
                                "--control-rate", AGENT_HZ])
                page.get_by_text(f"{rid} ({platform}): idle").wait_for(timeout=WAIT_S * 1000)
            obs.wait_alive({"baxter-1", "youbot-1"}, databank=True, sup=sup)
            for note in page.locator(".mantine-Notification-root button").all():
                note.click()  # "software WebGL" notices would cover the canvas
            page.get_by_text("Frame all robots").click()

            def both_drawn() -> bool:
                left, right = halves(coloured(canvas_shot(page)))
                return left > 500 and right > 200

            until(both_drawn, WAIT_S, "both robots drawn in the canvas", every=0.5)
            before = _steady(page)
            page.screenshot(path=str(log_folder(sup) / "view-before.png"))

            target = query_pose(obs.session, "baxter", *POSE).joints
            sup.spawn("send", ["send", "baxter-1", *map(str, POSE), "--connect", endpoint,
                               "--mode", "client", "--wait", "20"], expect_exit=True)
            assert sup.wait("send", WAIT_S) == 0
            until(lambda: at_pose(obs.states.snapshot().get("baxter-1"), target), WAIT_S,
                  "Baxter at the commanded pose", explain=obs.describe)
            page.get_by_text("right_arm ← right_shoulder → right-high, far").first.wait_for(
                timeout=WAIT_S * 1000)
            page.get_by_text("baxter-1 (baxter): idle").wait_for(timeout=WAIT_S * 1000)
            after = _steady(page)
            page.screenshot(path=str(log_folder(sup) / "view-after.png"))
    finally:
        obs.close()
    changed = np.abs(after - before).max(axis=2) > 40
    moved_left, moved_right = halves(changed)
    assert moved_left > 300, f"Baxter's half changed by only {moved_left} pixels"
    links_before, links_after = coloured(before), coloured(after)
    h, w = links_before.shape
    right = slice(w // 2, w)
    assert (links_before[:, right] != links_after[:, right]).sum() < 50, \
        "the youBot's half changed although only Baxter moved"


def _loads(page: Any, url: str) -> bool:
    try:
        page.goto(url, timeout=5000)
        return True
    except Exception:
        return False


def _steady(page: Any) -> np.ndarray:
    """A canvas screenshot once two in a row agree (the last state has been drawn)."""
    shot = canvas_shot(page)
    deadline = time.monotonic() + WAIT_S
    while time.monotonic() < deadline:
        time.sleep(0.3)  # let the browser draw another frame between two screenshots
        again = canvas_shot(page)
        if np.abs(again - shot).max() <= 8:
            return again
        shot = again
    pytest.fail("the view never settled to a steady picture")
