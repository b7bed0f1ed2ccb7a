"""One body vocabulary: the Motif/Labanotation body parts on every body that has them, read from
its eURDF (shipped, hand-labelled or proposed by the labeller), printed by ``describe``, carried
by catalogues, answers and acks; and ``kinesphere send`` of the same words to four bodies."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import msgspec
import pytest

from kinesphere import protocol as pr
from kinesphere.cli import main
from kinesphere.errors import KinesphereError
from kinesphere.eurdf import load_eurdf
from kinesphere.labeller import propose_eurdf
from kinesphere.platforms.platform import load_platform, platform_names
from kinesphere.robots.agent.fleet import RobotSpec
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.vocabulary import WORDS, vocabulary
from support.agents import DatabankProcess, running_fleet_host
from support.byor import robot_data
from support.network import KEYS, Hub
from support.paths import TOY
from support.wait import WAIT_S

ARTICULATED = ("baxter", "nao", "youbot", "packbot")


def said(e: Any) -> dict[str, tuple[str, str, str]]:
    """word -> (label, end, note)."""
    return {w.word: (w.label, w.end, w.note) for w in vocabulary(e)}


def test_every_body_answers_every_word_once_in_one_order() -> None:
    for name in platform_names():
        words = [w.word for w in vocabulary(load_platform(name).eurdf)]
        assert words == list(WORDS), name
    assert {"head", "torso", "chest", "right_arm", "left_upper_arm", "right_forearm",
            "left_hand", "right_leg", "left_thigh", "right_shin", "left_foot",
            "right_shoulder", "left_elbow", "right_wrist", "left_hip", "right_knee",
            "left_ankle", "neck"} <= set(WORDS)


def test_the_shipped_bodies_read_their_words_from_their_labels() -> None:
    baxter, nao, youbot, packbot, khepera = (said(load_platform(n).eurdf) for n in (
        "baxter", "nao", "youbot", "packbot", "khepera"))
    # Baxter: two arms with hands; no legs, and its head is part of the core
    assert baxter["right_arm"] == ("limb_11", "", "") and baxter["left_hand"][0] == "limb_23"
    assert baxter["right_upper_arm"][:2] == ("limb_11", "distal_12")
    assert baxter["right_wrist"][0] == "distal_13"
    assert baxter["left_leg"] == ("", "", "no left leg") and baxter["head"][0] == ""
    # NAO: arms without a hand location, legs with thighs and shins, a head
    assert nao["head"][0] == "limb_51" and nao["neck"][0] == "distal_51"
    assert nao["right_thigh"][:2] == ("limb_31", "distal_32")
    assert nao["left_shin"][0] == "limb_42" and nao["right_knee"][0] == "distal_32"
    assert nao["right_hand"][0] == "" and nao["left_foot"][0] == ""
    # one-armed bodies answer both sides with their arm, and say so
    for one in (youbot, packbot):
        for side in ("right", "left"):
            assert one[f"{side}_arm"] == ("limb_11", "", "the only arm")
            assert one[f"{side}_shoulder"][0] == "distal_11"
            assert one[f"{side}_forearm"][0] == "limb_12"
            assert one[f"{side}_upper_arm"][:2] == ("limb_11", "distal_12")
    assert youbot["right_hand"][0] == "limb_13"
    assert packbot["right_hand"][0] == "limb_14"  # limb_13 is PackBot's upper forearm
    assert packbot["left_wrist"][0] == "distal_14"
    # a body without limbs: only the torso, which is its core (the base translates)
    assert {w for w, (label, _, _) in khepera.items() if label} == {"torso", "chest"}
    assert khepera["torso"][0] == "c_1"


def test_a_brought_robots_words_come_from_the_labellers_aliases(tmp_path: Path) -> None:
    """iCub as ``kinesphere label`` proposes it from its URDF, and the hand-labelled toy arm."""
    icub = load_eurdf(propose_eurdf(robot_data() / "icub_description/robots/icub.urdf"))
    words = said(icub)
    assert words["right_arm"][0] == icub.limb("right_arm").name
    assert words["right_forearm"][0] == icub.limb("right_forearm").name
    assert words["left_upper_arm"][:2] == (icub.limb("left_arm").name,
                                           icub.origin("left_elbow").name)
    assert words["right_shin"][0] == icub.limb("right_shin").name
    assert words["head"][0] == icub.limb("head").name and words["right_foot"][0] == ""
    toy = said(load_eurdf(TOY / "toyarm.eurdf"))
    assert toy["right_arm"] == ("limb_11", "", "the only arm")
    assert toy["left_elbow"][0] == "distal_12"  # its location alias is elbow_loc
    assert toy["head"][0] == "" and toy["right_hand"][0] == ""


def test_an_alias_that_is_a_body_word_means_what_the_eurdf_says(tmp_path: Path) -> None:
    text = (TOY / "toyarm.eurdf").read_text()
    text = text.replace('alias="tail"', 'alias="head"').replace(
        '<body_part name="distal_21" set="J">', '<body_part name="distal_21" set="J" '
        'alias="neck">')
    words = said(load_eurdf(text))
    assert words["head"] == ("limb_21", "", "") and words["neck"] == ("distal_21", "", "")


@pytest.mark.parametrize("name", ARTICULATED)
def test_describe_prints_the_vocabulary(name: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["describe", name]) == 0
    out = capsys.readouterr().out
    section = out[out.index("body vocabulary"):]
    e = load_platform(name).eurdf
    for word, (label, end, note) in said(e).items():
        if label:
            line = next(x for x in section.splitlines() if x.split()[:1] == [word])
            assert line.split()[1] == label and (not end or f"up to {end}" in line)
            assert note in line
        else:
            assert word in section.splitlines()[-1]  # "lacks: ..."
    assert main(["describe", name, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert {w["word"]: w["label"] or "" for w in info["vocabulary"]} == {
        w: t[0] for w, t in said(e).items()}


def test_describe_prints_a_brought_robots_vocabulary(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "icub.eurdf"
    urdf = robot_data() / "icub_description/robots/icub.urdf"
    assert main(["label", str(urdf), "-o", str(out)]) == 0
    capsys.readouterr()
    assert main(["describe", str(out)]) == 0
    text = capsys.readouterr().out
    e = load_eurdf(out)
    assert f"right_upper_arm  {e.limb('right_arm').name} up to " in text
    assert f"left_shin        {e.limb('left_shin').name}" in text


def test_catalogues_carry_the_vocabulary_and_answers_say_what_was_meant() -> None:
    youbot = Ecl.open("youbot")
    cat = youbot.catalogue()
    assert [w.word for w in cat.vocabulary] == list(WORDS)
    assert pr.decode(pr.encode(cat), pr.Catalogue) == cat
    pose = youbot.query("left_arm", "left_shoulder", "left-high", 3)
    assert pose.limb == "limb_11" and [(w.word, w.label, w.note) for w in pose.words] == [
        ("left_arm", "limb_11", "the only arm"),
        ("left_shoulder", "distal_11", "the only arm's shoulder")]
    assert youbot.query("arm", "shoulder", "left-high", 3).words == []  # its own names
    baxter = Ecl.open("baxter")
    assert baxter.query("right_arm", "right_shoulder", "left-high", 3).words == []
    for limb, origin in (("left_leg", "left_hip"), ("right_arm", "right_ankle")):
        with pytest.raises(KinesphereError) as err:
            baxter.query(limb, origin, "forward-low", 3)
        assert err.value.code == "absent_part" and "baxter has no" in err.value.message
    with pytest.raises(KinesphereError) as err:  # a fixed base cannot move its torso
        baxter.query("torso", "torso", "forward-middle", 3)
    assert err.value.code == "cannot_translate"
    step = cat.translation_step or 0.0  # the core translates the base a step per size unit
    assert youbot.query("torso", "torso", "forward-middle", 2).translation == pytest.approx(
        [2 * step, 0.0, 0.0])


def test_body_words_are_bounded_and_version_1_peers_keep_working() -> None:
    word = {"word": "right_arm", "label": "limb_11"}
    too_many = {"type": "catalogue", "platform": "p", "core": [], "limbs": [], "joints": [],
                "sizes": [], "version": "x", "vocabulary": [word] * (pr.MAX_VOCABULARY + 1)}
    with pytest.raises(KinesphereError) as err:
        pr.decode(msgspec.msgpack.encode(too_many), pr.Catalogue)
    assert err.value.code == "malformed" and "vocabulary" in err.value.message
    long = {"type": "ack", "robot_id": "r", "sender": "s", "seq": 1, "stage": "accepted",
            "stamp_ns": 1, "words": [{**word, "note": "n" * (pr.MAX_TEXT + 1)}]}
    with pytest.raises(KinesphereError):
        pr.decode(msgspec.msgpack.encode(long), pr.Ack)

    class OldAck(msgspec.Struct):  # what a version-1 client declares: no words
        robot_id: str
        stage: str
        substitutions: list[Any] = []

    new = pr.Ack(robot_id="r", sender="s", seq=1, stage=pr.AckStage.ACCEPTED, stamp_ns=1,
                 words=[pr.BodyWord("right_arm", "limb_11", note="the only arm")])
    assert msgspec.msgpack.decode(pr.encode(new), type=OldAck).stage == "accepted"
    old = pr.decode(msgspec.msgpack.encode({"type": "ack", "robot_id": "r", "sender": "s",
                                            "seq": 1, "stage": "reached", "stamp_ns": 1}),
                    pr.Ack)
    assert old.words == []


def test_send_right_arm_from_the_right_shoulder_to_every_articulated_body(
    hub: Hub, databank: DatabankProcess, capsys: pytest.CaptureFixture[str],
) -> None:
    """``right_arm right_shoulder left-high 3`` (and ``left_arm``) answered by Baxter, NAO,
    youBot and PackBot, the one-armed bodies saying which arm; ``left_leg`` refused by
    Baxter with ``absent_part``."""
    _, endpoint = hub
    robots = [RobotSpec(p, f"voc-{p}") for p in ARTICULATED]
    zenoh_args = ["--connect", endpoint, "--prefix", KEYS.prefix, "--wait", str(WAIT_S),
                  "--timeout", str(WAIT_S)]
    with running_fleet_host(endpoint, robots, speed=4.0):
        for side in ("right", "left"):
            capsys.readouterr()
            assert main(["send", "all", f"{side}_arm", f"{side}_shoulder", "left-high", "3",
                         *zenoh_args]) == 0
            lines = {x.split(":")[0]: x for x in capsys.readouterr().out.splitlines()}
            assert set(lines) == {r.robot_id for r in robots}
            for r in robots:
                line = lines[r.robot_id]
                assert line.startswith((f"{r.robot_id}: reached", f"{r.robot_id}: clamped"))
                one_armed = r.platform in ("youbot", "packbot")
                assert (f"named {side}_arm -> limb_11 (the only arm)" in line) == one_armed
        assert main(["send", "voc-baxter", "left_leg", "left_hip", "forward-low", "3",
                     *zenoh_args]) == 1
        line = capsys.readouterr().out
        assert "REJECTED: absent_part: baxter has no left leg" in line
