"""The operator commands end to end over real Zenoh: send, play, estop and a headless gamepad
replay; user mistakes print ``error: ...`` and exit 2."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from test_client_support import KEYS, Inbox, hub

from kinesphere.cli import main
from kinesphere.clients import record
from kinesphere.clients.state import Action, ControllerState

__all__ = ["hub"]  # fixtures

ROBOTS = ("c1", "c2", "c3")


@pytest.fixture
def boxes(hub: tuple[zenoh.Session, str]) -> Iterator[dict[str, Inbox]]:
    b = {r: Inbox(hub[0], KEYS.command(r)) for r in ROBOTS}
    yield b
    for x in b.values():
        x.close()


def cli(endpoint: str, *args: str) -> int:
    return main([*args, "--connect", endpoint, "--prefix", KEYS.prefix])


def test_help_lists_the_operator_commands(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    for command in ("gamepad", "send", "play", "estop"):
        assert command in out


def test_send_one_command(hub: tuple[zenoh.Session, str], boxes: dict[str, Inbox]) -> None:
    code = cli(hub[1], "send", "c1", "limb_11", "distal_11", "Left-High", "3",
               "right_arm", "right_shoulder", "forward-low", "near")  # fmt: skip
    assert code == 0
    got = boxes["c1"].wait(lambda g: True, "the command").cmd
    assert [(p.limb, p.direction, p.size) for p in got.parts] == [
        ("limb_11", "left-high", 3.0), ("right_arm", "forward-low", 1.0)]  # fmt: skip
    assert got.deadman and got.ttl_ms == 0 and got.drive is None


def test_send_to_a_group_with_a_drive_held(
    hub: tuple[zenoh.Session, str], boxes: dict[str, Inbox]
) -> None:
    """One put on the group's key (agents run with --group pair subscribe there)."""
    pair = Inbox(hub[0], KEYS.group_command("pair"))
    try:
        code = cli(hub[1], "send", "group:pair", "arm", "shoulder", "left-low", "far",
                   "--drive", "forward", "0.4", "--for", "0.2")  # fmt: skip
        assert code == 0
        stop = pair.wait(lambda g: g.cmd.stop, "the stop").cmd
        moves = [c for c in pair.commands() if not c.stop]
        assert moves and stop.seq == moves[-1].seq + 1
        assert moves[0].drive is not None and moves[0].drive.speed == 0.4
        assert moves[0].ttl_ms == 300
        assert {g.key for g in pair.got} == {KEYS.group_command("pair")}
    finally:
        pair.close()
    for r in ROBOTS:  # (the group's stop came after any stray command)
        assert boxes[r].commands() == [], "robots outside the group hear nothing"


def test_a_group_named_like_a_robot_is_suggested(
    hub: tuple[zenoh.Session, str], capsys: pytest.CaptureFixture[str]
) -> None:
    field = Inbox(hub[0], KEYS.group_command("field"))
    try:
        assert cli(hub[1], "send", "field", "a", "b", "left", "1", "--wait", "0.5") == 2
    finally:
        field.close()
    assert "did you mean --target group:field?" in capsys.readouterr().err


def test_estop_reaches_every_robot_and_release_one(
    hub: tuple[zenoh.Session, str], boxes: dict[str, Inbox]
) -> None:
    assert cli(hub[1], "estop") == 0
    for r in ROBOTS:
        boxes[r].wait(lambda g: g.cmd.estop and g.key == KEYS.command("*"), f"e-stop at {r}")
    assert cli(hub[1], "estop", "--release") == 2, "whose e-stop: --target is required"
    assert cli(hub[1], "estop", "--release", "--target", "c2") == 0
    release = boxes["c2"].wait(lambda g: not g.cmd.estop, "the release").cmd
    assert release.release and release.deadman and not release.stop and release.parts == []


def test_play_a_phrase_file(
    hub: tuple[zenoh.Session, str], boxes: dict[str, Inbox], tmp_path: Path
) -> None:
    f = tmp_path / "p.toml"
    f.write_text("[[step]]\nduration = 0.2\nparts = ['limb_11 distal_11 left-high 2']\n")
    assert cli(hub[1], "play", str(f), "--target", "c3") == 0
    stop = boxes["c3"].wait(lambda g: g.cmd.stop, "the final stop")
    moves = [g for g in boxes["c3"].got if not g.cmd.stop]
    assert moves and all(g.cmd.parts[0].direction == "left-high" for g in moves)
    assert stop.at >= moves[-1].at


def test_gamepad_replays_a_recording_headless(
    hub: tuple[zenoh.Session, str], boxes: dict[str, Inbox], tmp_path: Path
) -> None:
    rec = tmp_path / "r.jsonl"
    push = ControllerState(rx=1.0, held=frozenset({Action.DEADMAN})).to_dict()
    lines = [{"kinesphere": "gamepad-recording", "version": 1}]
    lines += [{"t": k / 30, "state": push} for k in range(10)]
    lines += [{"t": 10 / 30, "state": ControllerState().to_dict()}]
    rec.write_text("\n".join(json.dumps(x) for x in lines) + "\n")
    again = tmp_path / "again.jsonl"
    code = cli(hub[1], "gamepad", "--replay", str(rec), "--headless", "--target", "c2",
               "--record", str(again))  # fmt: skip
    assert code == 0
    header, ticks = record.load(again)
    assert header["target"] == "c2" and header["rate_hz"] == 30.0
    assert any(Action.DEADMAN in cs.held for _, cs in ticks)
    boxes["c2"].wait(lambda g: g.cmd.stop, "the final stop")
    moves = [c for c in boxes["c2"].commands() if not c.stop]
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
        (["gamepad", "--replay", "/nonexistent.jsonl", "--headless"], "cannot read recording"),
        (["gamepad", "--mapping", "/nonexistent.toml", "--headless"], "cannot read mapping"),
    ],
)
def test_user_mistakes_are_explained(
    hub: tuple[zenoh.Session, str], capsys: pytest.CaptureFixture[str],
    args: list[str], message: str,
) -> None:  # fmt: skip
    assert cli(hub[1], *args) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err


def test_gamepad_with_its_hud_saves_a_screenshot(
    hub: tuple[zenoh.Session, str], tmp_path: Path
) -> None:
    png = tmp_path / "hud.png"
    code = cli(hub[1], "gamepad", "--duration", "0.3", "--screenshot", str(png))
    assert code == 0 and png.stat().st_size > 5000


def _kinesphere(endpoint: str, *args: str, env: dict[str, str]) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "kinesphere.cli", *args, "--connect", endpoint,
         "--prefix", KEYS.prefix],
        env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip


def test_without_a_display_the_hud_says_use_headless(hub: tuple[zenoh.Session, str]) -> None:
    """SDL would fall back to its offscreen driver and run a HUD nobody sees."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")}  # fmt: skip
    proc = _kinesphere(hub[1], "gamepad", "--duration", "0.2", env=env)
    assert proc.returncode == 2
    assert "no display: use --headless" in proc.stderr


def test_headless_without_a_controller_says_so(hub: tuple[zenoh.Session, str]) -> None:
    proc = _kinesphere(hub[1], "gamepad", "--headless", "--duration", "0.2", env=dict(os.environ))
    assert proc.returncode == 0
    assert "no game controller found" in proc.stderr
