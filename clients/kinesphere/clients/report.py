"""What robots are doing, in the operator's words: shared by the HUD and the command line.

A RobotState says ``estop`` with a detail written for protocol readers ("a command with
release=true"); the operator needs "E-STOP latched by you: press Start to release", or the
command that releases it. These
pure functions turn states (and, for the command line, acks) into such lines, so every client
says the same thing and tests can read it without a window.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from kinesphere import hints
from kinesphere.protocol import ANONYMOUS, OVERFLOW, Ack, AckStage, RobotState, Status
from kinesphere.words import degrees, signed

STALE_S = 0.5
"""A robot whose last state is older than this is shown as silent (states come at >= 50 Hz)."""
SLOW_S = 0.1
"""A state older than this shows a slow link (five states missed at 50 Hz)."""


@dataclass(frozen=True)
class Line:
    """One line of text and how it should look (``tone``: ok, info, warn, bad, dim)."""

    text: str
    tone: str = "info"


def odometry(base_pose: list[float]) -> str:
    """``x 1.20 y -0.40 m, heading +12°, 1.26 m from start`` (the odometry frame's origin is
    where the robot started)."""
    x, y, yaw = base_pose
    return (
        f"x {signed(x)} y {signed(y)} m, heading {degrees(yaw)}, "
        f"{math.hypot(x, y):.2f} m from start"
    )


def estop_words(st: RobotState, me: str, release_press: str = "") -> str:
    """Who latched the e-stop and how to release it: ``release_press`` is what this operator
    presses (``Start``, ``Enter``; "" on the command line, which names the command). Only the
    sender who latched an e-stop releases it."""
    by = st.estop_by
    if by and by == me:
        how = (f"press {release_press} to release" if release_press else
               f"release with '{hints.release_estop(st.robot_id)}'")
        return f"E-STOP latched by you: {how}"
    if by == OVERFLOW:
        return ("E-STOP latched by more senders than the robot names: no release clears "
                "that latch, only restarting its agent at the robot")
    if not by or by == ANONYMOUS:
        return (f"E-STOP latched by an operator without a name: release with "
                f"'{hints.release_estop(st.robot_id)}'")
    return (f"E-STOP latched by {by}: only {by} releases it "
            f"('{hints.release_estop(st.robot_id, by)}')")


def still_latched(robot_id: str, by: str) -> str:
    """A robot latched by another operator than this one, and the release that works."""
    if by == OVERFLOW:
        return f"{robot_id} by more senders than it names (only restarting its agent releases it)"
    return (f"{robot_id} by {by or 'an operator without a name'} "
            f"('{hints.release_estop(robot_id, by if by != ANONYMOUS else '')}')")


def status_words(st: RobotState, me: str = "", release_press: str = "") -> Line:
    """The status line of one robot, in operator words (the detail follows, when useful)."""
    s = st.status
    if s == Status.ESTOP:
        return Line(estop_words(st, me, release_press), "bad")
    detail = f": {st.detail}" if st.detail else ""
    if s == Status.MOVING:
        return Line(f"moving{detail}", "ok")
    if s == Status.IDLE:
        return Line(f"at rest{detail}", "dim")
    if s == Status.HOLDING:
        return Line(f"holding its position{detail}", "info")
    if s == Status.STOPPED:
        return Line("stopped; the next command moves it again", "warn")
    if s == Status.CLAMPED:
        joints = ", ".join(st.clamped) or "a joint"
        return Line(f"at a joint limit ({joints}): the pose was clamped", "warn")
    if s == Status.DATABANK_UNREACHABLE:
        return Line(f"no databank answers: holding its last pose{detail}", "bad")
    if s == Status.ERROR:
        return Line(f"refused the last command{detail}", "bad")
    return Line(f"{s}{detail}", "info")


def lease_words(st: RobotState, me: str) -> str:
    """Who the robot obeys now."""
    holder = st.lease_holder
    if not holder:
        return "control: free"
    return "control: you" if holder == me else f"control: {holder} (others are refused)"


def link_words(age_s: float) -> Line:
    """How fresh the robot's last state is: its link's health, at a glance."""
    if age_s > STALE_S:
        return Line(f"silent for {age_s:.1f} s: no state heard (link down or robot gone)", "bad")
    tone = "ok" if age_s < SLOW_S else "warn"
    return Line(f"link {age_s * 1000:.0f} ms", tone)


ANSWER_RANK = {AckStage.ACCEPTED: 0}
"""How much an ack says about what the robot does now: ``accepted`` least (every command of
a stream gets one; the motion's ``moving`` and final stage come once)."""


def current_answer(acks: Sequence[Ack]) -> Ack | None:
    """What the robot is doing with this operator's commands, from its acks in arrival order:
    the newest that is not a mere ``accepted`` (a motion is ``moving`` until its final
    stage, however many commands of the stream were accepted meanwhile), else the newest."""
    for ack in reversed(acks):
        if ack.stage != AckStage.ACCEPTED:
            return ack
    return acks[-1] if acks else None


STAGE_TONES = {AckStage.REACHED: "ok", AckStage.MOVING: "ok", AckStage.ACCEPTED: "info",
               AckStage.CLAMPED: "warn", AckStage.HOLDING: "warn", AckStage.STOPPED: "warn",
               AckStage.SUPERSEDED: "info", AckStage.LEASED: "info",
               AckStage.RELEASED: "info", AckStage.BLOCKED: "bad", AckStage.REJECTED: "bad",
               AckStage.ESTOPPED: "bad"}


def answer_headline(ack: Ack) -> Line:
    """The robot's answer in one or two words, for the largest line after the target:
    ``reached``, ``moving``, ``refused: lease_held``, ``holding``..."""
    stage = ack.stage
    if stage == AckStage.REJECTED:
        return Line(f"refused: {ack.code}", "bad")
    return Line(str(stage), STAGE_TONES.get(stage, "info"))


def answer_words(ack: Ack, age_s: float) -> Line:
    """The robot's answer to this operator, in full: ``#123 moving (0.1 s ago)``."""
    when = f"{age_s:.1f} s ago"
    if ack.stage == AckStage.REJECTED:
        return Line(f"refused your #{ack.seq} ({when}): {ack.code}: {ack.detail}", "bad")
    subs = ", ".join(f"{s.requested} -> {s.served}" for s in ack.substitutions)
    extra = f", served {subs}" if subs else ""
    detail = f": {ack.detail}" if ack.detail and ack.stage != AckStage.ACCEPTED else ""
    return Line(f"your #{ack.seq}: {ack.stage}{detail}{extra} ({when})",
                STAGE_TONES.get(ack.stage, "info"))


def robot_lines(st: RobotState, age_s: float, me: str = "", release_press: str = "",
                answer: Ack | None = None, answer_age_s: float = 0.0) -> list[Line]:
    """Every line the HUD shows for one robot: status, link health, odometry, lease and the
    last command it acted on, and its answer to this operator."""
    head = link_words(age_s) if age_s > STALE_S else status_words(st, me, release_press)
    lines = [head]
    if answer is not None:
        lines.append(answer_words(answer, answer_age_s))
    if age_s <= STALE_S:
        lines.append(link_words(age_s))
    lines.append(Line(odometry(st.base_pose), "dim"))
    extra = [lease_words(st, me)] if st.lease_holder else []
    if st.last_command_seq >= 0:
        extra.append(f"last command acted on #{st.last_command_seq}")
    if st.substitutions:
        extra.append("served " + ", ".join(
            f"{s.requested} -> {s.served} ({s.angle:.0f}°)" for s in st.substitutions))
    if extra:
        lines.append(Line("; ".join(extra), "dim"))
    return lines
