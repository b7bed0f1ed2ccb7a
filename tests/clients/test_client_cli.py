"""The operator commands end to end over real Zenoh against robots that answer as agents do:
send, play, estop and lease print one line per robot and exit 1 unless every addressed robot
accepted; a headless gamepad replay; user mistakes print ``error: ...`` and exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from kinesphere.cli import main
from kinesphere.clients.gamepad.inputs import ticks
from kinesphere.clients.gamepad.state import Action, ControllerState
from kinesphere.protocol import Ack, AckStage, Command, Substitution, encode
from support.clients import CommandInbox, Reply, StandIn, usual
from support.network import OWN_KEYS, Hub

ROBOTS = ("c1", "c2", "c3")
GROUPS = {"c1": ("pair",), "c2": ("pair",), "c3": ()}


@pytest.fixture
def boxes(hub: Hub) -> Iterator[dict[str, StandIn]]:
    """Three robots that answer as agents do; c1 and c2 are in group ``pair``."""
    b = {r: StandIn(hub[0], r, GROUPS[r]) for r in ROBOTS}
    yield b
    for x in b.values():
        x.close()


@contextmanager
def robot(hub: Hub, robot_id: str,
          answer: Callable[[Command], list[Reply]] | None) -> Iterator[StandIn]:
    r = StandIn(hub[0], robot_id, answer=answer)
    try:
        yield r
    finally:
        r.close()


def refusing(code: str, detail: str, when: Callable[[Command], bool] = lambda c: True
             ) -> Callable[[Command], list[Reply]]:
    """A robot that refuses the commands ``when`` selects with ``code``, and else obeys."""
    return lambda c: [(AckStage.REJECTED, code, detail, [])] if when(c) else usual(c)


def cli(endpoint: str, *args: str) -> int:
    return main([*args, "--connect", endpoint, "--prefix", OWN_KEYS.prefix])


def test_help_lists_the_operator_commands(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    for command in ("gamepad", "send", "play", "estop", "lease"):
        assert command in out


def test_send_one_command(
    hub: Hub, boxes: dict[str, StandIn], capsys: pytest.CaptureFixture[str]
) -> None:
    code = cli(hub[1], "send", "c1", "limb_11", "distal_11", "Left-High", "3", "right_arm",
               "right_shoulder", "forward-low", "near", "--sender", "alice")
    assert code == 0
    got = boxes["c1"].wait(lambda g: True, "the command").cmd
    assert [(p.limb, p.direction, p.size) for p in got.parts] == [
        ("limb_11", "left-high", 3.0), ("right_arm", "forward-low", 1.0)]
    assert got.deadman and got.ttl_ms == 0 and got.drive is None
    assert got.sender == "alice" and got.session, "robots order per (sender, session)"
    out, err = capsys.readouterr()
    assert out.splitlines() == ["c1: reached"]
    assert "1 of 1 robot(s) accepted" in err


def test_send_to_a_robot_that_rejects_exits_1_with_the_code(
    hub: Hub, capsys: pytest.CaptureFixture[str]
) -> None:
    why = "(limb_11, distal_11) has no direction left-low"
    with robot(hub, "c4", refusing("direction_unavailable", why)):
        assert cli(hub[1], "send", "c4", "limb_11", "distal_11", "left-low", "3") == 1
    out = capsys.readouterr().out
    assert out.splitlines() == [f"c4: REJECTED: direction_unavailable: {why}"]


def test_send_that_nobody_acknowledges_exits_1(
    hub: Hub, capsys: pytest.CaptureFixture[str]
) -> None:
    """The robot's subscription is there (the put goes out) but no ack ever comes back."""
    with robot(hub, "mute", None) as mute:
        code = cli(hub[1], "send", "mute", "limb_11", "distal_11", "left-low", "3",
                   "--timeout", "0.5")
        mute.wait(lambda g: True, "the command")
    assert code == 1
    out, err = capsys.readouterr()
    assert out.startswith("mute: NO ACKNOWLEDGEMENT within 0.5 s")
    assert "0 of 1 robot(s) accepted" in err


def test_send_prints_substitutions(
    hub: Hub, capsys: pytest.CaptureFixture[str]
) -> None:
    sub = Substitution("limb_11", "distal_11", "left-low", "left-forward-low", 35.26)

    def substituting(cmd: Command) -> list[Reply]:
        if not cmd.parts:
            return usual(cmd)
        return [(AckStage.ACCEPTED, "", "", [sub]), (AckStage.REACHED, "", "", [sub])]

    with robot(hub, "pb", substituting):
        assert cli(hub[1], "send", "pb", "arm", "shoulder", "left-low", "far") == 0
    assert capsys.readouterr().out.splitlines() == [
        "pb: reached; substituted left-low -> left-forward-low (35°)"]


def test_send_to_a_group_with_a_drive_held(
    hub: Hub, boxes: dict[str, StandIn], capsys: pytest.CaptureFixture[str]
) -> None:
    """One put on the group's key; the members are learnt from the robots' states."""
    code = cli(hub[1], "send", "group:pair", "arm", "shoulder", "left-low", "far",
               "--drive", "forward", "0.4", "--for", "0.2")
    assert code == 0
    for r in ("c1", "c2"):
        let_go = boxes[r].wait(lambda g: not g.cmd.deadman, "the deadman let go").cmd
        moves = [c for c in boxes[r].commands() if c.deadman]
        assert moves and let_go.seq == moves[-1].seq + 1 and not let_go.stop
        assert moves[0].drive is not None and moves[0].drive.speed == 0.4
        assert moves[0].ttl_ms == 300
        assert {g.key for g in boxes[r].got} == {OWN_KEYS.group_command("pair")}
    assert boxes["c3"].commands() == [], "robots outside the group hear nothing"
    assert capsys.readouterr().out.splitlines() == [
        "c1: holding: deadman released", "c2: holding: deadman released"]


def test_a_group_named_like_a_robot_is_suggested(
    hub: Hub, capsys: pytest.CaptureFixture[str]
) -> None:
    field = CommandInbox(hub[0], OWN_KEYS.group_command("field"))
    try:
        assert cli(hub[1], "send", "field", "a", "b", "left", "1", "--wait", "0.5") == 2
    finally:
        field.close()
    assert "did you mean 'group:field' (a group)?" in capsys.readouterr().err


def test_a_misspelt_robot_id_is_answered_with_the_nearest_live_one(
    hub: Hub, boxes: dict[str, StandIn], capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli(hub[1], "send", "c11", "a", "b", "left", "1", "--wait", "0.5") == 2
    err = capsys.readouterr().err
    missing = OWN_KEYS.command("c11")
    assert (f"no robot listens on {missing} (waited 0.5 s); live robots: c1 (fakebot), "
            "c2 (fakebot), c3 (fakebot) (did you mean 'c1'?)") in err


def test_estop_reaches_every_robot_and_each_acknowledges(
    hub: Hub, boxes: dict[str, StandIn], capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli(hub[1], "estop") == 0
    for r in ROBOTS:
        boxes[r].wait(lambda g: g.cmd.estop and g.key == OWN_KEYS.command("*"), f"e-stop at {r}")
    out, err = capsys.readouterr()
    assert out.splitlines() == [f"{r}: estopped" for r in ROBOTS]
    assert "E-STOP confirmed by all 3 live robot(s)" in err
    assert cli(hub[1], "estop", "--release") == 2, "whose e-stop: --target is required"
    assert cli(hub[1], "estop", "--release", "--target", "c2") == 0
    release = boxes["c2"].wait(lambda g: not g.cmd.estop, "the release").cmd
    assert release.release and release.deadman and not release.stop and release.parts == []
    assert capsys.readouterr().out.splitlines()[-1] == "c2: released"


def test_estop_with_no_robot_is_a_loud_failure(
    hub: Hub, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli(hub[1], "estop", "--timeout", "0.5") == 1
    assert "E-STOP REACHED NO ROBOT" in capsys.readouterr().err


def test_estop_that_a_live_robot_does_not_acknowledge_exits_1(
    hub: Hub, boxes: dict[str, StandIn], capsys: pytest.CaptureFixture[str]
) -> None:
    with robot(hub, "mute", None) as mute:
        assert cli(hub[1], "estop", "--timeout", "0.5") == 1
        assert len([g for g in mute.got if g.cmd.estop]) >= 2, "sent again while unanswered"
    out = capsys.readouterr().out.splitlines()
    (said,) = [ln for ln in out if ln.startswith("mute:")]
    assert said.startswith("mute: NOT CONFIRMED: alive (its last state came ")
    assert said.endswith(" s ago) but no e-stop acknowledgement within 0.5 s; make sure it is "
                         "stopped")
    assert {f"{r}: estopped" for r in ROBOTS} <= set(out)


def test_play_a_phrase_file(
    hub: Hub, boxes: dict[str, StandIn], tmp_path: Path
) -> None:
    f = tmp_path / "p.toml"
    f.write_text("[[step]]\nduration = 0.2\nparts = ['limb_11 distal_11 left-high 2']\n")
    assert cli(hub[1], "play", str(f), "--target", "c3") == 0
    let_go = boxes["c3"].wait(lambda g: not g.cmd.deadman, "the final let-go")
    moves = [g for g in boxes["c3"].got if g.cmd.deadman]
    assert moves and all(g.cmd.parts[0].direction == "left-high" for g in moves)
    assert let_go.at >= moves[-1].at


def test_play_goes_on_until_the_robot_reached_the_last_step_not_while_copies_are_replaced(
    hub: Hub, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An agent whose databank answers slowly supersedes the step's first command with the
    next copy (``superseded``), and one whose client stalled holds (the watchdog's
    ``holding``) until the next copy moves it on: neither ends the motion. Play streams on
    until the robot says ``reached`` (here for the 11th copy, heard after the 12th was sent),
    then lets go; the let-go holding the 12th copy's motion at the pose reached is not what
    the phrase did."""
    f = tmp_path / "p.toml"
    f.write_text("[[step]]\nduration = 0.1\nparts = ['limb_11 distal_11 left-high 2']\n")
    copies: list[Command] = []
    robots: list[StandIn] = []

    def ack(c: Command, stage: AckStage, detail: str = "") -> None:
        robots[0]._acks.put(encode(Ack(robot_id="yb", sender=c.sender, session=c.session,
                                       seq=c.seq, stage=stage, detail=detail,
                                       stamp_ns=time.time_ns())))

    def slow(c: Command) -> list[Reply]:
        if not c.deadman:  # as the agent: the let-go ends the motion it follows, and holds
            ack(copies[-1], AckStage.HOLDING, "deadman released: holding")
            return usual(c)
        copies.append(c)
        if len(copies) == 1:
            return [(AckStage.SUPERSEDED, "", "a newer command arrived first", [])]
        if len(copies) == 5:
            return [(AckStage.ACCEPTED, "", "", []),
                    (AckStage.HOLDING, "", "no new command within ttl_ms: holding", [])]
        if len(copies) == 12:
            ack(copies[-2], AckStage.REACHED)
        return [(AckStage.ACCEPTED, "", "", [])]

    with robot(hub, "yb", slow) as yb:
        robots.append(yb)
        assert cli(hub[1], "play", str(f), "--target", "yb") == 0
        yb.wait(lambda g: not g.cmd.deadman, "the final let-go")
        moves = [c for c in yb.commands() if c.deadman]
    assert len(moves) >= 12, "streamed until the robot reached"
    assert capsys.readouterr().out.splitlines() == ["yb: reached"]


def test_play_reports_a_refusal_once_per_robot_and_code(
    hub: Hub, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    f = tmp_path / "p.toml"
    step = "[[step]]\nduration = 0.3\nparts = ['limb_11 distal_11 {} 2']\n"
    f.write_text(step.format("left-high") + step.format("left-low"))
    why = "(limb_11, distal_11) has no direction left-low"
    lacks = refusing("direction_unavailable", why,
                     lambda c: any(p.direction == "left-low" for p in c.parts))
    with robot(hub, "yb", lacks) as yb:
        assert cli(hub[1], "play", str(f), "--target", "yb") == 1
        sent = [c for c in yb.commands() if c.deadman]
    refused = sum(any(p.direction == "left-low" for p in c.parts) for c in sent)
    out = capsys.readouterr().out.splitlines()
    assert out == [f"yb: REJECTED {refused} of {len(sent) + 1}: direction_unavailable: {why}"]


def test_lease_acquire_and_a_refusal_naming_the_holder(
    hub: Hub, boxes: dict[str, StandIn], capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli(hub[1], "lease", "acquire", "c1", "--sender", "alice") == 0
    cmd = boxes["c1"].wait(lambda g: True, "the lease command").cmd
    assert (cmd.lease, cmd.sender, cmd.parts, cmd.drive) == ("acquire", "alice", [], None)
    assert capsys.readouterr().out.splitlines() == ["c1: leased: lease acquire"]
    held = refusing("lease_held", "alice holds this robot's lease")
    with robot(hub, "c9", held):
        assert cli(hub[1], "lease", "acquire", "c9", "--sender", "bob") == 1
    assert "c9: REJECTED: lease_held: alice holds this robot's lease" in capsys.readouterr().out


def test_gamepad_replays_a_recording_headless(
    hub: Hub, boxes: dict[str, StandIn], tmp_path: Path
) -> None:
    rec = tmp_path / "r.mcap"
    push = ControllerState(rx=1.0, held=frozenset({Action.DEADMAN}))
    ticks.save(rec, [(k / 30, push) for k in range(10)] + [(10 / 30, ControllerState())])
    again = tmp_path / "again.mcap"
    code = cli(hub[1], "gamepad", "--replay", str(rec), "--headless", "--target", "c2",
               "--record", str(again))
    assert code == 0
    header, recorded = ticks.load(again)
    assert header["target"] == "c2" and header["rate_hz"] == 30.0
    assert any(Action.DEADMAN in cs.held for _, cs in recorded)
    boxes["c2"].wait(lambda g: g.cmd.lease == "release", "the lease given back at exit")
    cmds = boxes["c2"].commands()
    moves = [c for c in cmds if c.parts]
    assert [c.lease for c in cmds[len(moves):]] == ["", "release"], "let go, then release"
    assert not cmds[len(moves)].deadman
    assert 1 <= len(moves) <= 11  # a replay keeps to its clock: a busy CPU drops ticks
    assert {c.parts[0].direction for c in moves} == {"right-middle"}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["send", "c1", "limb_11", "distal_11", "upwards", "3"], "unknown direction 'upwards'"),
        (["send", "c1", "limb_11", "distal_11", "left"], "parts come in fours"),
        (["send", "c1"], "nothing to send"),
        (["send", "c/1", "a", "b", "left", "1"], "target 'c/1'"),
        (["send", "group:", "a", "b", "left", "1"], "target 'group:'"),
        (["send", "c1", "a", "b", "left", "1", "--drive", "up", "1"], "unknown direction"),
        (["send", "nobody", "a", "b", "left", "1", "--wait", "0.2"], "no robot listens"),
        (["play", "nonexistent_phrase"], "shipped phrases"),
        (["gamepad", "--replay", "/nonexistent.mcap", "--headless"], "cannot read recording"),
        (["gamepad", "--mapping", "/nonexistent.toml", "--headless"], "cannot read mapping"),
    ],
)
def test_user_mistakes_are_explained(
    hub: Hub, capsys: pytest.CaptureFixture[str],
    args: list[str], message: str,
) -> None:
    assert cli(hub[1], *args) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err


def test_gamepad_with_its_hud_saves_a_screenshot(
    hub: Hub, tmp_path: Path
) -> None:
    png = tmp_path / "hud.png"
    code = cli(hub[1], "gamepad", "--duration", "0.3", "--screenshot", str(png))
    assert code == 0 and png.stat().st_size > 5000


def _kinesphere(endpoint: str, *args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "kinesphere.cli", *args, "--connect", endpoint,
         "--prefix", OWN_KEYS.prefix],
        env=env, capture_output=True, text=True, timeout=120,
    )


@pytest.mark.processes
def test_without_a_display_the_hud_says_use_headless(hub: Hub) -> None:
    """SDL would fall back to its offscreen driver and run a HUD nobody sees."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")}
    proc = _kinesphere(hub[1], "gamepad", "--duration", "0.2", env=env)
    assert proc.returncode == 2
    assert "no display: use --headless" in proc.stderr


@pytest.mark.processes
def test_headless_without_a_controller_says_so(hub: Hub) -> None:
    proc = _kinesphere(hub[1], "gamepad", "--headless", "--duration", "0.2", env=dict(os.environ))
    assert proc.returncode == 0
    assert "no game controller found" in proc.stderr


def test_lease_without_arguments_says_what_to_give(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stopped:
        main(["lease"])
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert "the following arguments are required: acquire|take|release, TARGET" in err
