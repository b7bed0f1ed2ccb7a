"""``kinesphere router`` writes plain text into a log file: Zenoh's terminal colours (ANSI
escapes) only go to a terminal."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from kinesphere.zconfig import free_port
from support.paths import ROOT
from support.system import port_open
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes


def test_a_redirected_router_log_has_no_colour_codes(tmp_path: Path) -> None:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if k != "NO_COLOR"}
    with (tmp_path / "out.log").open("wb") as out, (tmp_path / "err.log").open("wb") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "kinesphere.cli", "router", "--listen",
             f"tcp/127.0.0.1:{port}"], cwd=ROOT, env=env, stdout=out, stderr=err)
        try:
            until(lambda: port_open(port), WAIT_S, "the router to listen")
        finally:
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(timeout=WAIT_S) == 0
    logged = (tmp_path / "out.log").read_bytes() + (tmp_path / "err.log").read_bytes()
    assert b"Zenoh can be reached at" in logged and b"router stopped" in logged
    assert b"\x1b[" not in logged, logged[:300]
