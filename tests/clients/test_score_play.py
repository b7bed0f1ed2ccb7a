"""``kinesphere play SCORE.json``: LabanotationSuite gestures performed by Baxter, NAO, youBot
and PackBot agents through the real databank (Zenoh on loopback), and what they did notated
back by others' code.

The measure is independent of everything that made the motion: the joint states each robot
reported at each keyframe (kept in ``--report``) go through yourdfpy's forward kinematics of
the platform's eURDF (:mod:`support.nested`, not kinesphere's kinematics nor the solver), and
each part's direction is written as a cell by LabanEditor's own ``labanProcessor.py``
(vendored unchanged). The score is read with the standard library's ``json``, not with
kinesphere's reader. The two gestures play at once, each by its own four robots (one fleet
host, two ``kinesphere play`` processes), and are tallied per platform.
"""

from __future__ import annotations

import json
import subprocess
import sys
from importlib import resources
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from kinesphere.cli import main
from kinesphere.robots.agent.fleet import RobotSpec
from kinesphere.vocabulary import lookup, vocabulary
from support.agents import DatabankProcess, running_fleet_host
from support.cells import Reachable, measured, player_vector, reachable, segments
from support.nested import MeasuredBody
from support.network import KEYS, Hub
from support.wait import WAIT_S

GESTURES = {"big2": "lab", "think_d_high_s": "think"}
"""Gesture -> the group of four robots that plays it (and the prefix of their ids)."""
PLATFORMS = ("baxter", "nao", "youbot", "packbot")
ROBOTS = [RobotSpec(p, f"{group}-{p}", (group,)) for group in GESTURES.values() for p in PLATFORMS]
AS_WRITTEN, WITHIN = 0.9, 45.0
SPEED = "0.1"
MEASURED = 8
"""At least two keyframes' arm cells the body can reach."""
PLAY_S = 600.0
"""Upper bound for one play process (it takes ~40 s): a hung one fails the test, not CI."""


def shipped_score(name: str) -> dict[str, dict[str, dict[str, list[str]]]]:
    res = resources.files("kinesphere.clients.orders").joinpath(f"scores/{name}.json")
    data: dict[str, dict[str, dict[str, list[str]]]] = json.loads(res.read_text())
    return data


@pytest.mark.realtime(longest=True)  # a minute, most of it robots moving: the others run beside
def test_play_scores_on_four_bodies_notated_back_by_labaneditor(
    hub: Hub, databank: DatabankProcess, tmp_path: Path,
    capsys: pytest.CaptureFixture[str], laban_editor: ModuleType,
) -> None:
    session, endpoint = hub
    zenoh_args = ["--connect", endpoint, "--prefix", KEYS.prefix, "--wait", str(WAIT_S),
                  "--timeout", str(WAIT_S)]
    reports = {}
    with running_fleet_host(endpoint, ROBOTS, speed=1.0):  # real time: no slips to catch up
        assert main(["play", "--check", "big2", "--target", "group:lab", *zenoh_args]) == 0
        check = capsys.readouterr().out
        plays = {name: subprocess.Popen(
            [sys.executable, "-m", "kinesphere.cli", "play", name, "--target", f"group:{group}",
             "--report", str(tmp_path / f"{name}.json"), "--speed", SPEED, *zenoh_args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for name, group in GESTURES.items()}
        try:
            played = {name: (p.communicate(timeout=PLAY_S), p.returncode)
                      for name, p in plays.items()}
        finally:  # a failed wait leaves no player behind
            for p in plays.values():
                if p.poll() is None:
                    p.kill()
                    p.wait()
        for name, group in GESTURES.items():
            (out, err), code = played[name]
            reports[name] = json.loads((tmp_path / f"{name}.json").read_text())
            failed = [k["said"] for r in reports[name]["robots"] for k in r["keyframes"]
                      if k["said"]]
            assert code == (1 if failed else 0), out  # a blocked keyframe is no success
            for r in reports[name]["robots"]:  # a late keyframe is said per robot, never silently
                late = [f'{k["keyframe"]} +{k["late_ms"]} ms' for k in r["keyframes"]
                        if k["late_ms"] > 0]
                assert not late or f'{r["robot"]} late at {len(late)} keyframe(s): ' \
                    f'{", ".join(late)}' in err, (late, err)
            if name == "think_d_high_s":  # it turns the body: a fixed base says it did not
                baxter = [ln for ln in out.splitlines()
                          if ln.startswith(f"{group}-baxter (baxter): ")]
                assert "rotation not performed (a fixed base)" in baxter[-1], out
            print(out, file=sys.stderr)
    turning = [(r["platform"], k) for r in reports["think_d_high_s"]["robots"]
               for k in r["keyframes"]]
    for platform, kf in turning:  # the score turns the body 60 degrees right, then back
        if platform == "baxter":
            assert kf["base_yaw"] is None
        elif not kf["said"] and (kf["late_ms"] == 0 or kf["index"] == 2):
            # on time, or the turn held a second time (a body blocked mid-way holds there)
            assert abs(np.degrees(kf["base_yaw"]) - kf["turn_deg"]) < 2, (platform, kf)
    assert "lab-youbot: big2 Position1: right elbow Right Low, right wrist Left Forward " \
        "Normal: not performed (direction_unavailable: " in check  # what the databank refuses
    assert "head         not performed: no head" in check.split("lab-nao")[0]
    assert "rotation     not performed: a fixed base" in check.split("lab-nao")[0]
    written = {next(iter(shipped_score(name))): next(iter(shipped_score(name).values()))
               for name in GESTURES}
    assert all(kf["q"] for name in GESTURES for r in reports[name]["robots"]
               for kf in r["keyframes"]), "a keyframe without a state to measure"
    tally = measured([reports[name] for name in GESTURES], written, laban_editor, by="platform")
    for platform in PLATFORMS:
        t = tally[platform]
        print(t.line(platform))
        if platform in ("youbot", "packbot"):  # one arm: the right-arm columns
            assert t.performs == ["right elbow", "right wrist"], t.performs
        if platform in ("baxter", "nao"):
            assert t.reachable >= MEASURED, (platform, t)  # not vacuous
            assert t.same_reachable >= AS_WRITTEN * t.reachable, (platform, t)
            assert max(t.angles) <= WITHIN, (platform, t.angles)
    nao = tally["nao"]  # the head, measured where it looks
    assert nao.head_reachable >= len(GESTURES), nao
    assert nao.head_same >= AS_WRITTEN * nao.head_reachable, nao


def test_reachable_cells_come_from_the_joint_limits(laban_editor: ModuleType) -> None:
    """Baxter's upper arm cannot hang straight down (``s1`` stops at 1.047 rad, 30 degrees
    short): the sampled limits find no Place Low for it, and find it for NAO's; NAO's head
    looks up and down far enough for Laban's high and low levels but not straight up."""
    def arm(platform: str) -> Reachable:
        body = MeasuredBody(platform)
        parts = segments(body)
        limb = lookup(vocabulary(body.eurdf))["right_arm"].label
        return reachable(platform, limb, parts["right elbow"], parts["right wrist"],
                         laban_editor)

    baxter, nao = arm("baxter"), arm("nao")
    assert not baxter.has("Place Low") and nao.has("Place Low")
    assert baxter.has("Forward Low") and baxter.has("Right Low")
    assert baxter.has_inner("Place Low", player_vector("Place", "Low"), "Place Low")
    body = MeasuredBody("nao")
    head = segments(body)["head"]
    looks = reachable("nao", lookup(vocabulary(body.eurdf))["head"].label, head, head,
                      laban_editor).cells()
    assert {"Forward Normal", "Forward High", "Forward Low", "Left Normal"} <= looks, looks
    assert "Place High" not in looks and "Place Low" not in looks, looks
