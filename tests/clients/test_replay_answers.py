"""``kinesphere replay`` says what the robots made of the commands it put, from their acks.

A real agent on a real Zenoh hub acts on a recorded session the first time it is replayed;
replayed again as recorded, it drops every command as stale (its own ordering rules, and its
own count of dropped commands agrees): the replay says so, names the ``--restamp`` replay
that works (run as printed: the robot acts on it) and exits 1. Ctrl-C during a replay says
it was interrupted and exits 130, with what was put so far.
"""

from __future__ import annotations

import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from kinesphere import zconfig
from kinesphere.cli import main
from kinesphere.clients.mcaplog import McapWriter
from kinesphere.protocol import AckStage, Command
from support.agents import AckWatch, running_agent
from support.network import KEYS, Hub
from support.paths import ROOT
from support.wait import WAIT_S

pytestmark = pytest.mark.processes

QUOTED = re.compile(r"'(kinesphere [^']+)'")


def recording(path: Path, robot: str, n: int, gap_s: float) -> Path:
    """``n`` commands to ``robot`` ``gap_s`` apart, each from a sender of its own without a
    session (so none replaces another while it waits, and none takes the robot's lease)."""
    t0 = time.time_ns()
    with McapWriter(path) as w:
        for i in range(n):
            at = t0 + int(i * gap_s * 1e9)
            w.write(KEYS.command(robot), Command(seq=1, sent_ns=at, deadman=True, ttl_ms=0,
                                                 sender=f"rec-{i}"), at)
    return path


def test_a_replay_every_robot_dropped_as_stale_says_so_and_names_restamp(
        hub: Hub, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = recording(tmp_path / "session.mcap", "rp-1", 3, 0.02)
    ep = ["--connect", hub.endpoint]
    with running_agent(hub.endpoint, "khepera", "rp-1") as (_, watch):
        capsys.readouterr()
        assert main(["replay", str(path), *ep]) == 0, capsys.readouterr().err
        err = capsys.readouterr().err
        assert "the robots' answers to 3 command(s), per robot: 3 acted on" in err, err

        assert main(["replay", str(path), *ep]) == 1
        err = capsys.readouterr().err
        assert "3 acted on" not in err and "replayed 3 commands message(s)" in err, err
        assert "0 acted on; 3 dropped as stale (rp-1 3)" in err, err
        hint = [shlex.split(c)[1:] for c in QUOTED.findall(err)]
        assert hint == [["replay", str(path), "--restamp"]], err
        st = watch.wait(lambda st: st.dropped >= 3, "the robot's own count of drops")
        assert st.dropped == 3

        assert main([*hint[0], *ep]) == 0, capsys.readouterr().err
        assert "per robot: 3 acted on" in capsys.readouterr().err


def test_a_replay_nobody_answers_exits_1(hub: Hub, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    """A subscriber heard the commands (the replay's wait for listeners passes), but no robot
    acknowledged any: the replay waited for the robot's liveliness token too, and says it
    never came."""
    path = recording(tmp_path / "session.mcap", "rp-none", 2, 0.02)
    with zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s:
        sub = s.declare_subscriber(KEYS.command("rp-none"), lambda sample: None)
        try:
            capsys.readouterr()  # --wait: room for the subscriber's match (gossip, ~0.5 s)
            assert main(["replay", str(path), "--connect", hub.endpoint, "--wait", "2"]) == 1
        finally:
            zconfig.undeclare(sub)
    err = capsys.readouterr().err
    assert "no robot answered any of the 2 command(s)" in err, err
    assert "not seen alive within --wait 2 s: robot(s) rp-none" in err, err


def test_an_interrupted_replay_says_so_and_exits_130(hub: Hub, tmp_path: Path) -> None:
    path = recording(tmp_path / "long.mcap", "rp-2", 40, 0.5)
    with running_agent(hub.endpoint, "khepera", "rp-2"), \
            zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s:
        acks = AckWatch(s, "rp-2")
        proc = subprocess.Popen(
            [sys.executable, "-m", "kinesphere.cli", "replay", str(path),
             "--connect", hub.endpoint], cwd=ROOT, stderr=subprocess.PIPE, text=True)
        try:
            acks.wait(lambda a: a.sender == "rec-0" and a.stage == AckStage.ACCEPTED,
                      "the robot acting on the first command")
        finally:
            sent = time.monotonic()
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=WAIT_S)
            took = time.monotonic() - sent
            acks.close()
    assert proc.returncode == 130, err
    put = re.search(r"replay interrupted: (\d+) commands message\(s\) from .* put before it "
                    r"was stopped", err)
    assert put is not None and 1 <= int(put[1]) < 40, err
    assert "acted on" in err, err
    print(f"replay: Ctrl-C to exit {took:.2f} s")
