"""LabanotationSuite score files: the shipped gestures read as the standard library's ``json``
reads them (another reader of the same files), and every malformed score refused before
anything moves with a ``malformed`` error naming the gesture and the keyframe."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path
from typing import Any

import pytest

from kinesphere.cli import main
from kinesphere.errors import KinesphereError
from kinesphere.scores import COLUMNS, MAX_KEYFRAMES, MAX_SCORE_BYTES, load_score, parse_score

SCORES = resources.files("kinesphere.clients.orders").joinpath("scores")
SHIPPED = sorted(p.name for p in SCORES.iterdir() if p.name.endswith(".json"))


def test_a_handful_of_gestures_is_shipped_with_the_mit_notice() -> None:
    assert len(SHIPPED) >= 5
    notice = SCORES.joinpath("LICENSE").read_text()
    assert "MIT License" in notice and "Microsoft Corporation" in notice


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scores_read_as_json_reads_them(name: str) -> None:
    text = SCORES.joinpath(name).read_text()
    raw: dict[str, dict[str, dict[str, list[str]]]] = json.loads(text)
    score = parse_score(text, name)
    assert [g.name for g in score.gestures] == list(raw)
    for g in score.gestures:
        frames = raw[g.name]
        assert [k.name for k in g.keyframes] == list(frames)
        for k in g.keyframes:
            want = frames[k.name]
            assert k.time_ms == int(want["start time"][0])
            for column in COLUMNS:
                assert [k.cells[column].horizontal, k.cells[column].level] == want[column]
            turn, deg = want["rotation"]
            assert k.turn_deg == (-1 if turn == "ToRight" else 1) * float(deg)


def one(**changes: Any) -> dict[str, Any]:
    kf: dict[str, Any] = {"start time": ["1"], "duration": ["0"], "rotation": ["ToRight", "0"]}
    kf.update({c: ["Place", "Low"] for c in COLUMNS})
    kf.update({k.replace("_", " "): v for k, v in changes.items()})
    return kf


def score(*frames: dict[str, Any]) -> str:
    return json.dumps({"wave": {f"Position{i}": f for i, f in enumerate(frames)}})


@pytest.mark.parametrize(("text", "words"), [
    (score(one(head=["Forwards", "Normal"])), "keyframe 'Position0' head: unknown direction "
     "'Forwards' (did you mean 'Forward'?)"),
    (score(one(right_elbow=["Left", "Middle"])), "keyframe 'Position0' right elbow: unknown "
     "level 'Middle'"),
    (score(one(), one(left_knee=["Left", "Low"], start_time=["600"])),
     "keyframe 'Position1': unknown part 'left knee'"),
    (score(one(start_time=["-5"])), "start time must be a whole number of milliseconds"),
    (score(one(start_time=["500"]), one(start_time=["400"])),
     "keyframe 'Position1': start time 400 ms is not later than Position0's 500 ms"),
    (score(one(start_time=["x"])), "start time 'x' is not a number"),
    (score(one(start_time=["nan"])), "start time must be finite"),
    (score(one(rotation=["Around", "30"])), "rotation must be [ToLeft|ToRight, degrees]"),
    (score(one(head=["Forward"])), "head must be [direction, level]"),
    (json.dumps({"wave": {}}), "gesture 'wave' has no keyframe"),
    (json.dumps({}), "holds no gesture"),
    ("{not json", "is not JSON"),
    (json.dumps({"wave": {"Position0": {"head": "Forward"}}}), "is not a LabanotationSuite score"),
])
def test_a_malformed_score_names_the_gesture_keyframe_and_problem(text: str, words: str
                                                                ) -> None:
    with pytest.raises(KinesphereError) as err:
        parse_score(text, "bad.json")
    assert err.value.code == "malformed"
    assert words in err.value.message, err.value.message
    assert err.value.message.startswith("bad.json")


def test_a_score_of_too_many_keyframes_is_refused_before_it_is_read() -> None:
    frames = [one(start_time=[str(i + 1)]) for i in range(MAX_KEYFRAMES + 1)]
    with pytest.raises(KinesphereError, match=f"at most {MAX_KEYFRAMES}"):
        parse_score(score(*frames), "long.json")


def test_a_file_too_large_is_refused_by_its_size(tmp_path: Path) -> None:
    big = tmp_path / "big.json"
    with big.open("wb") as f:
        f.truncate(MAX_SCORE_BYTES + 1)
    with pytest.raises(KinesphereError, match="bytes; a score file has at most"):
        load_score(big)
    with pytest.raises(KinesphereError, match="cannot read score"):
        load_score(tmp_path / "missing.json")


@pytest.mark.parametrize(("args", "words"), [
    (["big2", "--speed", "0"], "--speed must be 0.01..100, got 0"),
    (["big2", "--gesture", "bigg"], "big2.json has no gesture 'bigg' (did you mean 'big2'?)"),
    (["left_high", "--speed", "2"], "--speed applies to a score (SCORE.json), not to the "
     "phrase left_high"),
    (["big2", "--report", "no/such/folder/r.json"], "no folder no/such/folder to write it in"),
    (["nosuch.json"], "no score file nosuch.json; shipped scores: big2"),
])
def test_play_refuses_a_bad_score_or_option_before_it_looks_for_robots(
        args: list[str], words: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["play", *args, "--connect", "tcp/127.0.0.1:9", "--wait", "0.1"]) == 2
    err = capsys.readouterr().err
    assert words in err and err.rstrip().endswith("[malformed]"), err
