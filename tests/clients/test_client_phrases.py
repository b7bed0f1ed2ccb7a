"""Movement phrases: the shipped ones parse and say what they should; playing streams each
step for its duration and ends with a stop."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from kinesphere.clients.link import Sequencer
from kinesphere.clients.orders import phrases
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from support.clients import CommandInbox, client_link, sentinel
from support.files import refused
from support.network import OWN_KEYS, Hub
from support.wait import WAIT_S


def test_shipped_phrases_parse() -> None:
    assert phrases.shipped() == ["left_high", "packbot_retreat", "packbot_sweep", "tour_guide"]
    for name in phrases.shipped():
        p = phrases.load_phrase(name)
        assert p.steps and p.description
    left_high = phrases.load_phrase("left_high.toml")
    first = left_high.steps[0].parts[0]
    assert (first.limb, first.origin, first.direction, first.size) == (
        "limb_11", "distal_11", "left-high", 3.0)
    assert len(phrases.load_phrase("tour_guide").steps) == 4


def test_packbot_sweep_drives_forward_while_sweeping_low_left_and_right() -> None:
    sweep = phrases.load_phrase("packbot_sweep")
    dirs = [s.parts[0].direction for s in sweep.steps]
    assert dirs == ["left-forward-low", "right-forward-low"] * 2
    for s in sweep.steps:
        assert s.drive is not None and s.drive.direction == "forward-middle" and s.drive.speed > 0
        assert s.parts[0].size == 3.0 and s.parts[0].limb == "arm"


def test_packbot_retreat_pulls_back_high_while_driving_back() -> None:
    last = phrases.load_phrase("packbot_retreat").steps[-1]
    assert last.parts[0].direction == "back-high"
    assert last.drive is not None and last.drive.direction == "back-middle"


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("name = 'x'", "at least one"),
        ("[[step]]\nduration = 1\nparts = ['a b upward 3']", "unknown direction 'upward'"),
        ("[[step]]\nduration = 1\nparts = ['a b left']", "LIMB ORIGIN DIRECTION SIZE"),
        ("[[step]]\nduration = 1\nparts = ['a b left huge']", "near, mid, far"),
        ("[[step]]\nduration = 1\ndrive = 'left-high 0.5'", "base drives along"),
        ("[[step]]\nduration = 1\ndrive = 'left 2'", "speed must be 0..1"),
        ("[[step]]\nparts = ['a b left 1']", "duration"),
        ("[[step]]\nduration = 1", "needs parts, a drive"),
        ("[[step]]\nduration = 1\nspeed = 1\nparts = ['a b left 1']", "unknown ['speed']"),
        ("colour = 1\n[[step]]\nduration = 1\nparts = ['a b left 1']", "unknown ['colour']"),
        ("[[step]]\nduration = 1\nparts = [{limb = 'a', direction = 'left', size = 1}]",
         "missing ['origin']"),
    ],
)
def test_bad_phrases_are_explained(tmp_path: Path, text: str, match: str) -> None:
    assert match in refused(phrases.load_phrase, tmp_path, text, code=None).message


def test_an_unknown_phrase_lists_the_shipped_ones() -> None:
    with pytest.raises(KinesphereError, match="shipped phrases: left_high, packbot_retreat"):
        phrases.load_phrase("no_such_phrase")


@pytest.fixture
def boxes(hub: Hub) -> Iterator[dict[str, CommandInbox]]:
    b = {r: CommandInbox(hub[0], OWN_KEYS.command(r)) for r in ("p1", "p2")}
    yield b
    for x in b.values():
        x.close()


def test_play_streams_each_step_for_its_duration(
    hub: Hub, boxes: dict[str, CommandInbox], tmp_path: Path
) -> None:
    f = tmp_path / "two.toml"
    f.write_text(
        "[[step]]\nduration = 0.3\nparts = ['arm shoulder Left-Low far']\ndrive = 'forward 0.3'\n"
        "[[step]]\nduration = 0.3\nparts = [{limb = 'arm', origin = 'shoulder', "
        "direction = 'right low', size = 2.5}]\n"
    )
    phrase = phrases.load_phrase(f)
    keys = [OWN_KEYS.command(r) for r in boxes]
    with client_link(hub[1], watch=False) as link:
        assert link.wait_subscribers(keys, WAIT_S) == []
        sent = phrases.play(link, phrase, keys, Sequencer("play-test", 300), rate_hz=50.0)
        sentinel(link, keys, list(boxes.values()))
    for box in boxes.values():
        got = [g for g in box.got if g.cmd.sender == "play-test"]
        assert len(got) == sent
        first = [g for g in got if g.cmd.parts and g.cmd.parts[0].direction == "left-low"]
        second = [g for g in got if g.cmd.parts and g.cmd.parts[0].direction == "right-low"]
        assert all(g.cmd.drive is not None for g in first)
        assert all(g.cmd.drive is None and g.cmd.parts[0].size == 2.5 for g in second)
        assert len(first) <= 16 and len(second) <= 16  # 0.3 s at 50 Hz (fewer on a busy CPU)
        assert first and second and 0.25 < second[0].at - first[0].at < 0.6
        assert not got[-1].cmd.deadman and got[-1] is not second[-1], "then let go"
        assert [g.cmd.seq for g in got] == list(range(len(got)))


def test_direction_spellings_are_normalised() -> None:
    part = phrases.parse_part("right_arm right_shoulder Right-forward-Low mid", "test")
    assert part.direction == Direction.RIGHT_FORWARD_LOW.slug and part.size == 2.0
