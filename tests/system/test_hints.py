"""Every command kinesphere tells a user to run, run where it is printed: each hint of
``kinesphere.hints`` is taken out of the message that printed it and run as written (plus
only the Zenoh endpoint of the test's network), and what it promises happens.

``test_hints_source.py`` keeps every such command in ``kinesphere.hints``; the router's hint
runs in ``test_router_down.py``. The buttons the HUD names (Start, Enter, K) are pressed in
``tests/clients/test_client_input.py``.
"""

from __future__ import annotations

import re
import shlex
import shutil
import time
from pathlib import Path

import pytest

from kinesphere import hints, zconfig
from kinesphere.cli import main
from kinesphere.clients.gamepad.inputs import ticks
from kinesphere.clients.gamepad.state import ControllerState
from kinesphere.clients.mcaplog import McapWriter
from kinesphere.clients.report import estop_words
from kinesphere.errors import KinesphereError
from kinesphere.eurdf import plain_urdf
from kinesphere.procs import Supervisor
from kinesphere.protocol import Command
from kinesphere.robots.agent.runtime import Agent, AgentOptions
from kinesphere.services.databank.client import query_catalogue, record_pose
from kinesphere.services.ecl.store import DATA_DIR
from support.agents import CommandSender, running_agent
from support.clients import CommandInbox
from support.network import OWN_KEYS, Hub
from support.paths import TOY_EURDF
from support.system import Observer
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

QUOTED = re.compile(r"'(kinesphere [^']+)'")


def commands(text: str) -> list[list[str]]:
    """The quoted ``kinesphere ...`` commands of a message, as argument lists (without the
    program's name)."""
    return [shlex.split(found)[1:] for found in QUOTED.findall(text)]


def error_of(capsys: pytest.CaptureFixture[str], *argv: str) -> str:
    """Run a command that must fail with a user error; its message."""
    capsys.readouterr()
    assert main(list(argv)) == 2, argv
    err = capsys.readouterr().err
    assert err.startswith("error: "), err
    return err


def test_the_release_lease_and_status_hints_of_a_live_robot(
    hub: Hub, capsys: pytest.CaptureFixture[str]
) -> None:
    """An e-stop's detail (and the HUD's words for another operator's latch) name the
    release that works; the take-over and status commands do what they say."""
    ep = ["--connect", hub.endpoint]
    with running_agent(hub.endpoint, "youbot", "yb-h") as (_, watch), \
            zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s:
        op = CommandSender(s, "yb-h", sender="hint-op")
        st = watch.after(op.send(estop=True), lambda st: st.status == "estop", "the e-stop")
        (release,) = commands(st.detail)
        assert release == ["estop", "--release", "--target", "yb-h", "--sender", "hint-op"]
        assert commands(estop_words(st, "someone-else")) == [release]
        assert main([*release, *ep]) == 0
        watch.wait(lambda st: st.status != "estop", "the release")

        alice = CommandSender(s, "yb-h", sender="alice")
        watch.after(alice.send(lease="acquire"), lambda st: st.lease_holder == "alice",
                    "alice's lease")
        assert main([*hints.take_lease("yb-h").argv, *ep, "--sender", "bob"]) == 0
        watch.wait(lambda st: st.lease_holder == "bob", "bob's lease")
        main(["lease", "release", "yb-h", *ep, "--sender", "bob"])
        op.close()
        alice.close()

        capsys.readouterr()
        assert main([*hints.status().argv, *ep]) == 0
        assert "yb-h" in capsys.readouterr().out


def test_a_brought_robots_hints(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                monkeypatch: pytest.MonkeyPatch) -> None:
    """``platform new`` prints describe and ecl build for the folder; the files it writes
    say how they began; a folder without its databank names the build that makes it."""
    urdf = tmp_path / "toy.urdf"
    urdf.write_text(plain_urdf(TOY_EURDF.read_text()))
    assert main(["platform", "new", "toyb", "--urdf", str(urdf), "--dir", str(tmp_path)]) == 0
    folder = tmp_path / "toyb"
    describe, build = commands(capsys.readouterr().out)
    assert describe == list(hints.describe(str(folder)).argv) and build[:2] == ["ecl", "build"]
    assert main(describe) == 0
    assert main(build) == 0 and (folder / "toyb.sqlite").is_file()
    began, check = commands((folder / "platform.toml").read_text())
    assert began == ["platform", "new", "toyb", "--urdf", "toy.urdf"] and check == describe
    monkeypatch.chdir(tmp_path)  # where the URDF is, as the comment assumes
    assert main([*began, "--dir", str(tmp_path / "again")]) == 0
    (vsam,) = commands((folder / "vsam.toml").read_text())
    assert vsam == build

    (folder / "toyb.sqlite").unlink()
    get = ["ecl", "get", str(folder), "limb_11", "distal_11", "forward-middle", "3"]
    (rebuild,) = commands(error_of(capsys, *get))
    assert main(rebuild) == 0
    assert main(get) == 0


def test_the_databank_and_agent_hints(sup: Supervisor, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    """Nobody answering a query names the databank to start; a databank refusing records
    names the one that accepts them (on the same file); a robot not heard names the agent to
    start. Each is started as printed, and the command that failed then works."""
    copy = tmp_path / "youbot.sqlite"
    shutil.copyfile(DATA_DIR / "youbot.sqlite", copy)
    with zconfig.loopback_hub() as (hub, endpoint):
        join = ["--connect", endpoint, "--listen", zconfig.LOOPBACK_ANY_PORT]
        obs = Observer(config=zconfig.loopback_config(endpoint))
        try:
            with pytest.raises(KinesphereError) as nobody:
                query_catalogue(hub, "youbot", timeout=0.3)
            (serve,) = commands(nobody.value.message)
            assert serve == ["databank", "serve"]
            sup.spawn("databank", [*serve, *join])
            until(lambda: bool(obs.alive.databanks), WAIT_S, "the databank", guard=sup.check)
            assert query_catalogue(hub, "youbot", timeout=WAIT_S).platform == "youbot"
            sup.stop("databank")
            until(lambda: not obs.alive.databanks, WAIT_S, "the databank gone")

            sup.spawn("readonly", ["databank", "serve", "--db", f"youbot={copy}", *join])
            until(lambda: bool(obs.alive.databanks), WAIT_S, "the databank", guard=sup.check)
            joints = {"arm_joint_1": 2.9, "arm_joint_2": 1.0}
            args = ("youbot", "limb_11", "distal_11", "forward-middle", 2, joints)
            with pytest.raises(KinesphereError) as refused:
                record_pose(hub, *args, timeout=WAIT_S)
            assert refused.value.code == "forbidden"
            (writable,) = commands(refused.value.message)
            assert writable == ["databank", "serve", "--db", f"youbot={copy}", "--allow-writes"]
            sup.stop("readonly")
            until(lambda: not obs.alive.databanks, WAIT_S, "the databank gone")
            sup.spawn("writable", [*writable, *join])
            until(lambda: bool(obs.alive.databanks), WAIT_S, "the databank", guard=sup.check)
            assert record_pose(hub, *args, timeout=WAIT_S).joints

            record = ["ecl", "record", "youbot", "--db", str(copy), "--limb", "arm", "--origin",
                      "shoulder", "--direction", "forward-middle", "--size", "2",
                      "--from-robot", "yb-c", "--timeout", "0.5", "--connect", endpoint]
            (agent,) = commands(error_of(capsys, *record))
            assert agent == ["agent", "youbot", "--id", "yb-c"]
            sup.spawn("agent", [*agent, *join])
            obs.wait_alive({"yb-c"}, databank=True, sup=sup)
            assert main([*record[:-4], "--timeout", str(WAIT_S), "--connect", endpoint]) == 0
        finally:
            obs.close()


def test_the_recording_hints(hub: Hub, tmp_path: Path,
                             capsys: pytest.CaptureFixture[str]) -> None:
    """A session of messages given to the gamepad names ``kinesphere replay``; a gamepad's
    ticks given to ``replay`` name ``gamepad --replay``. Both run (the session's command to a
    robot that acts on it: a replay nobody answers exits 1)."""
    session = tmp_path / "session.mcap"
    cmd = Command(seq=0, sent_ns=time.time_ns(), deadman=False, ttl_ms=0, sender="rec")
    with McapWriter(session, {"prefix": OWN_KEYS.prefix}) as w:
        w.write(OWN_KEYS.command("rr"), cmd, time.time_ns())
    ep = ["--connect", hub.endpoint, "--prefix", OWN_KEYS.prefix]
    (replay,) = commands(error_of(capsys, "gamepad", "--replay", str(session), "--headless",
                                  *ep))
    assert replay == ["replay", str(session)]
    with zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s:
        robot = Agent("khepera", "rr", s, AgentOptions(prefix=OWN_KEYS.prefix)).start()
        # another subscriber of the command key on the hub, which routes for nobody: the
        # replay waits for the robot itself, not just for someone listening
        box = CommandInbox(hub.session, OWN_KEYS.command("rr"))
        try:
            assert main([*replay, *ep]) == 0  # the robot acted on it
            box.wait(lambda g: g.cmd.sender == "rec", "the replayed command")
        finally:
            box.close()
            robot.close()

    hands = tmp_path / "hands.mcap"
    ticks.save(hands, [(0.0, ControllerState()), (0.1, ControllerState())])
    (gamepad,) = commands(error_of(capsys, "replay", str(hands), *ep))
    assert gamepad == ["gamepad", "--replay", str(hands), "--headless"]
    assert main([*gamepad, *ep]) == 0


def test_the_platforms_hint() -> None:
    assert main(hints.platforms().argv) == 0
