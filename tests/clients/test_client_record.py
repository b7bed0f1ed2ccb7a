"""Recording a gamepad session and replaying it reproduces the same commands."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path

import pygame
import pytest

from kinesphere import zconfig
from kinesphere.clients import mcaplog
from kinesphere.clients import targets as tg
from kinesphere.clients.gamepad import mapfile
from kinesphere.clients.gamepad.inputs import pad, ticks
from kinesphere.clients.gamepad.state import NEUTRAL, Action, ControllerState
from kinesphere.clients.gamepad.teleop import Teleop, run
from kinesphere.clients.options import TeleopOptions
from kinesphere.clients.recording.traffic import replay
from kinesphere.errors import KinesphereError
from kinesphere.protocol import Command
from support.clients import CommandInbox, Pad, Script, client_link, sentinel
from support.network import OWN_KEYS, Hub
from support.wait import WAIT_S


@pytest.fixture
def box(hub: Hub) -> Iterator[CommandInbox]:
    inbox = CommandInbox(hub[0], OWN_KEYS.command("rec"))
    yield inbox
    inbox.close()


def test_a_replay_sends_what_the_recorded_session_sent(
    hub: Hub, box: CommandInbox, pygame_up: None, tmp_path: Path
) -> None:
    pygame.event.clear()
    inp = pad.PygameInput(mapfile.load())
    p = Pad()
    script = Script(inp, {
        0: lambda: p.plug().deadman().right(-1.0, 0.0),
        3: lambda: p.axis(pygame.CONTROLLER_AXIS_TRIGGERLEFT, 1.0),
        5: lambda: p.left(0.0, -0.7).tap(pygame.CONTROLLER_BUTTON_X),
        8: lambda: p.right(1.0, 0.0),
        11: lambda: p.deadman(False),
        13: lambda: None,
    })
    polled: list[ControllerState] = []

    class Spy:
        def poll(self) -> ControllerState:
            polled.append(script.poll())
            return polled[-1]

    path = tmp_path / "session.mcap"
    with client_link(hub[1]) as link:
        assert link.wait_subscribers([OWN_KEYS.command("rec")], WAIT_S) == []
        with ticks.TickRecorder(path, target="rec") as rec:
            op = Teleop(link, mapfile.load(), tg.robot("rec"), TeleopOptions(rate_hz=60.0))
            run(op, Spy(), record=rec, finished=lambda: script.finished)
        sentinel(link, [OWN_KEYS.command("rec")], [box])
        first = box.commands()
        header, recorded = ticks.load(path)
        assert header["target"] == "rec" and header["version"] == ticks.VERSION
        assert [cs for _, cs in recorded] == polled, "every tick is recorded as it was seen"
        assert any(Action.ORIGIN_NEXT in cs.pressed for _, cs in recorded)

        times = iter([t for t, _ in recorded] + [recorded[-1][0] + 1.0] * 5)
        replay = ticks.TickReplay(recorded, clock=lambda: next(times))
        op = Teleop(link, mapfile.load(), tg.robot("rec"), TeleopOptions(rate_hz=60.0))
        run(op, replay, finished=lambda: replay.finished)
        sentinel(link, [OWN_KEYS.command("rec")], [box])
    second = box.commands()[len(first) :]

    def content(cmds: list[Command]) -> list[tuple[object, ...]]:
        return [(c.parts, c.drive, c.deadman, c.stop, c.lease) for c in cmds]

    assert len(first) == 13 and not first[-2].deadman and first[-1].lease == "release"
    assert content(second) == content(first)
    assert {c.parts[0].direction for c in first[:-2]} == {"left-middle", "left-low", "right-low"}


def test_a_slower_replay_keeps_every_tap() -> None:
    recorded = [
        (0.00, ControllerState(held=frozenset({Action.DEADMAN}))),
        (0.01, ControllerState(pressed=frozenset({Action.LIMB_NEXT}))),
        (0.02, ControllerState(pressed=frozenset({Action.ORIGIN_NEXT}))),
        (0.03, ControllerState(rx=0.5)),
    ]
    times = iter([0.0, 0.025, 0.5, 0.6])
    replay = ticks.TickReplay(recorded, clock=lambda: next(times))
    assert replay.poll().held == {Action.DEADMAN}
    got = replay.poll()
    assert got.pressed == {Action.LIMB_NEXT, Action.ORIGIN_NEXT}
    assert not replay.finished
    end = replay.poll()
    assert replay.finished and replay_equal(end, NEUTRAL)
    assert replay.poll().pressed == frozenset()


def replay_equal(a: ControllerState, b: ControllerState) -> bool:
    return replace(a, source="x") == replace(b, source="x")


def _mcap(path: Path, meta: dict[str, str] | None, data: bytes = b"") -> None:
    with mcaplog.McapWriter(path, meta) as w:
        if data:
            w.write_json(ticks.TOPIC, ControllerState, data, 1_000)


GOOD = {"kinesphere": "gamepad-recording", "version": "2", "start_ns": "0"}


@pytest.mark.parametrize(
    ("make", "match"),
    [
        (lambda f: f.write_bytes(b""), "not a readable MCAP file"),
        (lambda f: f.write_text('{"kinesphere": "gamepad-recording", "version": 1}\n'),
         "not a readable MCAP file"),  # the old JSON lines
        (lambda f: _mcap(f, None), "no gamepad-recording header"),  # e.g. 'kinesphere record'
        (lambda f: _mcap(f, {**GOOD, "version": "1"}), "version '1'"),
        (lambda f: _mcap(f, {**GOOD, "start_ns": "soon"}), "header"),
        (lambda f: _mcap(f, GOOD, b"not json"), "tick 1"),
        (lambda f: _mcap(f, GOOD, b"[1, 2]"), "tick 1"),
        (lambda f: None, "cannot read recording"),
    ],
)
def test_bad_recordings_are_explained(
    tmp_path: Path, make: Callable[[Path], object], match: str
) -> None:
    f = tmp_path / "bad.mcap"
    make(f)
    with pytest.raises(KinesphereError, match=match) as info:
        ticks.load(f)
    assert info.value.code == "malformed"


def test_a_recording_keeps_its_header_ticks_and_times(tmp_path: Path) -> None:
    recorded = [(k / 30, ControllerState(rx=k / 10, held=frozenset({Action.DEADMAN})))
             for k in range(10)]
    ticks.save(tmp_path / "r.mcap", recorded, target="c2", rate_hz=30.0)
    header, got = ticks.load(tmp_path / "r.mcap")
    assert header == {"kinesphere": "gamepad-recording", "version": 2, "target": "c2",
                      "rate_hz": 30.0}
    assert [cs for _, cs in got] == [cs for _, cs in recorded]
    assert [round(t, 9) for t, _ in got] == [round(t, 9) for t, _ in recorded]
    # one format for every recording: the MCAP reader sees a channel with a JSON schema
    (raw, *_) = mcaplog.messages(tmp_path / "r.mcap")
    assert (raw.schema, raw.topic) == ("kinesphere.ControllerState", "gamepad/state")
    assert list(mcaplog.read(tmp_path / "r.mcap")) == []  # no message to put on the wire
    with zconfig.loopback_hub() as (net, _):
        with pytest.raises(KinesphereError, match="kinesphere gamepad --replay"):
            replay(net, tmp_path / "r.mcap")
