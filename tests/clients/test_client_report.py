"""What the HUD and the command line say about a robot, in the operator's words (pure)."""

from __future__ import annotations

import math
import time

import msgspec
import pytest

from kinesphere.clients.report import (
    STALE_S,
    Line,
    answer_headline,
    current_answer,
    robot_lines,
)
from kinesphere.protocol import Ack, AckStage, RobotState, Substitution
from kinesphere.words import degrees

ME = "gamepad-me"


def state(**kw: object) -> RobotState:
    base = RobotState(
        robot_id="pb-1", platform="packbot", seq=1, stamp_ns=time.time_ns(),
        joint_names=["turret"], q=[0.0], qd=[0.0], base_pose=[0.0, 0.0, 0.0], status="idle",
        last_command_seq=-1)
    return msgspec.structs.replace(base, **kw)


def ack(stage: AckStage, **kw: object) -> Ack:
    base = Ack(robot_id="pb-1", sender=ME, seq=12, stage=stage, stamp_ns=time.time_ns())
    return msgspec.structs.replace(base, **kw)


def texts(st: RobotState, age_s: float = 0.12, release_press: str = "") -> list[str]:
    return [ln.text for ln in robot_lines(st, age_s, ME, release_press)]


def test_an_estop_says_who_latched_it_and_how_to_release_it() -> None:
    mine = texts(state(status="estop", estop_by=ME, detail="a command with release=true"),
                 release_press="Start")
    assert mine[0] == "E-STOP latched by you: press Start to release"
    keyboard = texts(state(status="estop", estop_by=ME), release_press="Enter")
    assert keyboard[0] == "E-STOP latched by you: press Enter to release"
    theirs = texts(state(status="estop", estop_by="alice"))
    assert theirs[0] == ("E-STOP latched by alice: only alice releases it ('kinesphere estop "
                         "--release --target pb-1 --sender alice')")
    one_shot = robot_lines(state(status="estop", estop_by=ME), 0.1, ME)
    assert one_shot[0].text == ("E-STOP latched by you: release with 'kinesphere estop "
                                "--release --target pb-1'")
    assert all("release=true" not in t for t in mine + theirs), "no protocol words"


def test_odometry_and_link_health_are_always_shown() -> None:
    far = texts(state(base_pose=[34.0, 0.5, -0.001]), age_s=0.012)
    assert far[1:3] == ["link 12 ms", "x +34.00 y +0.50 m, heading +0°, 34.00 m from start"]
    assert robot_lines(state(), 0.012)[1].tone == "ok"
    assert robot_lines(state(), 0.3)[1] == Line("link 300 ms", "warn")
    assert degrees(-0.004) == "+0°" and degrees(math.pi) == "+180°"


def test_a_silent_robot_says_so_instead_of_its_last_status() -> None:
    silent = texts(state(status="moving"), age_s=2.5)
    assert silent[0] == "silent for 2.5 s: no state heard (link down or robot gone)"
    assert texts(state(status="moving"), age_s=STALE_S / 2)[0] == "moving"


def test_a_robot_at_rest_says_so_whatever_the_deadman() -> None:
    assert texts(state(status="idle", detail="at target"))[0] == "at rest: at target"


@pytest.mark.parametrize(("holder", "words"), [
    (ME, "control: you"), ("alice", "control: alice (others are refused)")])
def test_the_lease_holder_and_the_last_command_acted_on(holder: str, words: str) -> None:
    lines = texts(state(lease_holder=holder, last_command_seq=7, substitutions=[
        Substitution("limb_11", "distal_11", "left-low", "left-forward-low", 35.3)]))
    assert lines[3] == (f"{words}; last command acted on #7; "
                        "served left-low -> left-forward-low (35°)")
    assert len(texts(state())) == 3, "nothing to say about a free robot that got no command"


def test_the_answer_to_this_operator() -> None:
    refused = ack(AckStage.REJECTED, code="lease_held", detail="alice holds this robot's lease")
    lines = robot_lines(state(), 0.1, ME, answer=refused, answer_age_s=0.31)
    assert (lines[1].text, lines[1].tone) == (
        "refused your #12 (0.3 s ago): lease_held: alice holds this robot's lease", "bad")
    assert answer_headline(refused) == Line("refused: lease_held", "bad")
    moving = ack(AckStage.MOVING, substitutions=[
        Substitution("limb_11", "distal_11", "left-low", "left-forward-low", 35.3)])
    line = robot_lines(state(), 0.1, ME, answer=moving, answer_age_s=0.1)[1]
    assert line.text == "your #12: moving, served left-low -> left-forward-low (0.1 s ago)"
    assert robot_lines(state(), 0.1, ME, answer=ack(AckStage.BLOCKED))[1].tone == "bad"


def test_the_current_answer_is_what_the_robot_does_not_the_last_accepted() -> None:
    """A stream's commands are each accepted; the motion is moving until its final stage."""
    stream = [ack(AckStage.ACCEPTED), ack(AckStage.MOVING), ack(AckStage.ACCEPTED),
              ack(AckStage.ACCEPTED)]
    assert current_answer(stream) is stream[1]
    done = [*stream, ack(AckStage.REACHED), ack(AckStage.ACCEPTED)]
    assert current_answer(done) is done[4]
    assert current_answer([ack(AckStage.ACCEPTED)]) is not None
    assert current_answer([]) is None
