"""What robots are doing, in the operator's words: shared by the HUD and the command line.

A RobotState says ``estop`` with a detail written for protocol readers ("a command with
release=true"); the operator needs "E-STOP latched by you: press Start to release". These
pure functions turn states (and, for the command line, acks) into such lines, so every client
says the same thing and tests can read it without a window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from kinesphere.protocol import Ack, AckStage, RobotState, Status

STALE_S = 0.5
"""A robot whose last state is older than this is shown as silent (states come at >= 50 Hz)."""


@dataclass(frozen=True)
class Line:
    """One line of text and how it should look (``tone``: ok, info, warn, bad, dim)."""

    text: str
    tone: str = "info"


def odometry(base_pose: list[float]) -> str:
    """``x 1.20 y -0.40 m, heading 12°, 1.26 m from start`` (the odometry frame's origin is
    where the robot started)."""
    x, y, yaw = base_pose
    return (
        f"x {x:+.2f} y {y:+.2f} m, heading {math.degrees(yaw):+.0f}°, "
        f"{math.hypot(x, y):.2f} m from start"
    )


def estop_words(st: RobotState, me: str, start_releases: bool) -> str:
    """Who latched the e-stop and how to release it."""
    by = st.estop_by
    if by and by == me:
        how = "press Start to release" if start_releases else "release with kinesphere estop"
        return f"E-STOP latched by you: {how}"
    who = f"by {by}" if by else "(by another operator)"
    return f"E-STOP latched {who}: release with kinesphere estop --release --target {st.robot_id}"


def status_words(st: RobotState, me: str = "", start_releases: bool = True) -> Line:
    """The status line of one robot, in operator words (the detail follows, when useful)."""
    s = st.status
    if s == Status.ESTOP:
        return Line(estop_words(st, me, start_releases), "bad")
    detail = f": {st.detail}" if st.detail else ""
    if s == Status.MOVING:
        return Line(f"moving{detail}", "ok")
    if s == Status.IDLE:
        return Line("idle, ready for a command", "dim")
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


def answer_words(ack: Ack, age_s: float) -> Line:
    """The robot's newest answer to this operator: ``#123 moving (0.1 s ago)``."""
    when = f"{age_s:.1f} s ago"
    if ack.stage == AckStage.REJECTED:
        return Line(f"refused your #{ack.seq} ({when}): {ack.code}: {ack.detail}", "bad")
    subs = ", ".join(f"{s.requested} -> {s.served}" for s in ack.substitutions)
    extra = f", served {subs}" if subs else ""
    tone = "warn" if ack.stage == AckStage.BLOCKED else "dim"
    return Line(f"your #{ack.seq}: {ack.stage}{extra} ({when})", tone)


def robot_lines(st: RobotState, age_s: float, me: str = "", start_releases: bool = True,
                answer: Ack | None = None, answer_age_s: float = 0.0) -> list[Line]:
    """Every line the HUD shows for one robot: status, odometry and link, lease and the last
    command it acted on, and its newest answer to this operator."""
    if age_s > STALE_S:
        head = Line(f"silent for {age_s:.1f} s: no state heard (link down or robot gone)", "bad")
    else:
        head = status_words(st, me, start_releases)
    link = f"link {age_s * 1000:.0f} ms" if age_s < 1.0 else f"link {age_s:.1f} s"
    lines = [head, Line(f"{odometry(st.base_pose)}; {link}", "dim")]
    extra = [lease_words(st, me)] if st.lease_holder else []
    if st.last_command_seq >= 0:
        extra.append(f"last command acted on #{st.last_command_seq}")
    if st.substitutions:
        extra.append("served " + ", ".join(
            f"{s.requested} -> {s.served} ({s.angle:.0f}°)" for s in st.substitutions))
    if extra:
        lines.append(Line("; ".join(extra), "dim"))
    if answer is not None:
        lines.append(answer_words(answer, answer_age_s))
    return lines
