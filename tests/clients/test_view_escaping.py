"""Text from the network shows as text in ``kinesphere view``, in headless Chromium.

Before: the side panel rendered Markdown with raw HTML, so a command whose limb was
``<iframe srcdoc="<script>top.document.title='OWNED'</script>">`` ran script in the
operator's page (and script there could hide an e-stop); so did a state's ``detail``. Here
stand-in robots on the test hub put states and commands whose every shown field is markup
(``detail``, ``status``, ``estop_by``, ``lease_holder``, a command's limb, origin and
direction, an ack's code, a substitution's names, the robot id itself); a real youBot body
is served, so labels are drawn too. The page must run no script, hold no element the
senders wrote, and show their text as written.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack
from typing import Any

import pytest
import zenoh

from kinesphere import protocol as pr
from kinesphere import zconfig
from kinesphere.clients.view.app import FleetView
from kinesphere.platforms.platform import load_platform
from kinesphere.services.databank.body import body_model
from support.hostile import IMG, SCRIPT
from support.network import OWN_KEYS as KEYS
from support.network import Hub
from support.view import browser_page
from support.wait import WAIT_S

pytestmark = pytest.mark.processes  # Chromium

MARK = "<b>bold</b>"


def _img(n: int) -> str:
    """An image whose error handler would retitle the page (short enough for a name)."""
    return IMG.replace("OWNED", f"OWNED{n}")


ROBOTS = {
    _img(0): dict(status="moving", detail=SCRIPT, lease_holder=_img(1)),
    "estopped": dict(status="estop", estop_by=_img(2), detail=f"{MARK} [x](javascript:1)"),
    "statused": dict(status=_img(3), detail="# heading\n\n* item"),
}


@pytest.fixture
def fleet(hub: Hub) -> Iterator[tuple[FleetView, zenoh.Session]]:
    body = body_model(load_platform("youbot"))

    def answer(query: zenoh.Query) -> None:
        with query:
            query.reply(query.key_expr, pr.encode(body))

    with ExitStack() as stack:
        robots = stack.enter_context(zconfig.session(config=zconfig.loopback_config(hub.endpoint)))
        queryable = hub.session.declare_queryable(KEYS.body("youbot"), answer, complete=True)
        tokens = [robots.liveliness().declare_token(KEYS.alive_robot(rid)) for rid in ROBOTS]
        stack.callback(zconfig.undeclare, queryable, *tokens)
        view = FleetView(hub.session, KEYS, port=zconfig.free_port())
        stack.callback(view.close)
        stop = threading.Event()
        loop = threading.Thread(target=view.run, args=(stop,), daemon=True)
        loop.start()
        stack.callback(loop.join, 5.0)
        stack.callback(stop.set)
        yield view, robots


def _put_all(robots: zenoh.Session, seq: int) -> None:
    part = pr.SpatialCommand(limb=_img(4), origin=_img(5), direction=MARK, size=2.0)
    for rid, fields in ROBOTS.items():
        state: dict[str, Any] = dict(
            robot_id=rid, platform="youbot", seq=seq, stamp_ns=time.time_ns(), joint_names=[],
            q=[], qd=[], base_pose=[0.0, 0.0, 0.0], last_command_seq=seq, substitutions=[
                pr.Substitution(limb=_img(6), origin="o", requested=MARK, served=_img(7),
                                angle=10.0)])
        state.update(fields)
        robots.put(KEYS.state(rid), pr.encode(pr.RobotState(**state)))
        cmd = pr.Command(seq=seq, sent_ns=time.time_ns(), parts=[part], deadman=True,
                         ttl_ms=0, sender=_img(8), session="s")
        robots.put(KEYS.command(rid), pr.encode(cmd))
        robots.put(KEYS.ack(rid), pr.encode(pr.Ack(
            robot_id=rid, sender=_img(8), session="s", seq=seq, stage=pr.AckStage.REJECTED,
            code=_img(9), stamp_ns=time.time_ns())))


def test_network_text_shows_as_text_and_runs_nothing(fleet: tuple[FleetView, zenoh.Session]
                                                     ) -> None:
    view, robots = fleet
    with browser_page() as page:
        title = None
        deadline = time.monotonic() + WAIT_S
        seq = 0
        text = ""
        while time.monotonic() < deadline:
            _put_all(robots, seq)
            seq += 1
            if title is None:
                try:
                    page.goto(f"http://127.0.0.1:{view.port}/", timeout=5000)
                    title = page.title()
                except Exception:
                    continue
            text = page.inner_text("body")
            if SCRIPT in text and all(f"OWNED{n}" in text for n in (0, 1, 2, 3, 4, 5, 9)) \
                    and len(view.drawings) == len(ROBOTS):
                break
            time.sleep(0.2)  # the next states; the page is polled, never assumed ready
        # the senders' text is shown as written (in the text the wait ended on: read again
        # after the last put, a robot may show as silent) ...
        print(text)
        assert SCRIPT in text, text[:3000]
        for n in (0, 1, 2, 3, 4, 5, 9):
            assert _img(n) in text, (n, text[:3000])
        assert f"{MARK} [x](javascript:1)" in text and "# heading * item" in text
        # ... and nothing the senders wrote became an element or ran
        for selector in ("iframe", "[srcdoc]", "[onerror]", "a[href^='javascript']"):
            assert page.locator(selector).count() == 0, selector
        assert page.locator("b", has_text="bold").count() == 0
        assert "OWNED" not in page.title() and page.title() == title
        assert len(view.drawings) == len(ROBOTS)  # labels drawn as well (canvas text)
