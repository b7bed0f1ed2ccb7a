"""A performed score notated back: where each part pointed, written as LabanEditor writes it.

After each keyframe, the joint states a robot *reported* are put through its eURDF's forward
kinematics (:class:`~kinesphere.pointing.Pointing`, from the databank's body model: nothing
of the solver that chose the pose) and each performed part's direction is notated with
LabanEditor's rule (:func:`~kinesphere.notation.notate`). Per robot, the share of (keyframe,
arm part) cells that come back as the score wrote them, and the angle between each part and
the score's direction, is the paper's "same movement" made a number.

The share counts the columns the body performs: a part it lacks is skipped (and said once),
but a cell whose direction the databank refused (the body cannot point there), or that no
state came back for, counts against it. ``Place Normal`` has no direction to compare and is
left out. The report (``--report FILE.json``) holds every
cell, the state it was measured on (its ``seq``, joint names and values, so anyone can measure
it again) and each robot's share.
"""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence
from pathlib import Path

import msgspec

from kinesphere.casting import ARM_COLUMNS, Casting
from kinesphere.notation import angle_to, notate
from kinesphere.pointing import Pointing
from kinesphere.protocol import RobotState
from kinesphere.scores import COLUMNS, Keyframe


class CellReport(msgspec.Struct, frozen=True):
    """One (keyframe, column) on one robot: what the score wrote, what came back."""

    column: str
    written: str
    notated: str = ""
    """The cell the measured direction is written as ("" when not performed)."""
    angle_deg: float | None = None
    """Degrees between the measured direction and the score's (None: none to compare)."""
    performed: bool = True
    why: str = ""
    """Why the cell was not performed (the part is missing, the databank refused it)."""

    @property
    def as_written(self) -> bool:
        return self.performed and self.notated == self.written

    @property
    def counted(self) -> bool:
        """Whether the cell counts in the share: every cell but Place Normal."""
        return self.written != "Place Normal"


class KeyframeReport(msgspec.Struct):
    gesture: str
    index: int
    keyframe: str
    time_ms: int
    cells: list[CellReport]
    late_ms: int = 0
    """How much later than the keyframe's time the robot said it arrived (0: on time)."""
    said: str = ""
    """What the robot said about the keyframe's command when not plainly (refused, blocked)."""
    stages: list[str] = []
    """The stages the robot acknowledged the keyframe's commands with (the first few)."""
    state_seq: int = -1
    """``RobotState.seq`` of the state measured (-1: none arrived)."""
    joint_names: list[str] = []
    q: list[float] = []
    base_yaw: float | None = None
    turn_deg: float = 0.0


class Share(msgspec.Struct, frozen=True):
    cells: int
    as_written: int
    share: float
    median_angle_deg: float | None
    worst_angle_deg: float | None


class RobotReport(msgspec.Struct):
    robot: str
    platform: str
    performs: dict[str, str]
    skipped: dict[str, str]
    turns: bool
    keyframes: list[KeyframeReport] = []
    arms: Share | None = None
    head: Share | None = None


class ScoreReport(msgspec.Struct):
    score: str
    gestures: list[str]
    speed: float
    robots: list[RobotReport]


def measure(pointing: Pointing, casting: Casting, kf: Keyframe, state: RobotState | None,
            refused: Mapping[str, str]) -> list[CellReport]:
    """Every column of ``kf`` on one robot, from the state it reported (None: none came)."""
    roles = [r for r in casting.roles if r.column not in refused]
    directions = []
    if state is not None and roles:
        joints = dict(zip(state.joint_names, state.q, strict=True))
        directions = pointing.directions([(r.start, r.end) for r in roles], joints)
    found = dict(zip((r.column for r in roles), directions, strict=False))
    out = []
    for column in COLUMNS:
        written = kf.cells[column]
        why = casting.skipped.get(column) or refused.get(column, "")
        if not why and state is None:
            why = "no state reported"
        v = found.get(column)
        if why or v is None:
            out.append(CellReport(column, str(written), performed=False,
                                  why=why or "the part has no length"))
            continue
        cell = notate(v)
        angle = angle_to(v, written)
        out.append(CellReport(column, str(written), str(cell) if cell else "",
                              None if angle is None else round(angle, 2)))
    return out


def share(keyframes: Sequence[KeyframeReport], columns: Sequence[str]) -> Share | None:
    """The share of ``columns``' cells notated back as written, with the angles' median and
    worst (over the cells performed); None when the score wrote none of them."""
    cells = [c for k in keyframes for c in k.cells if c.column in columns and c.counted]
    if not cells:
        return None
    good = sum(c.as_written for c in cells)
    angles = [c.angle_deg for c in cells if c.angle_deg is not None]
    return Share(len(cells), good, round(good / len(cells), 4),
                 round(statistics.median(angles), 1) if angles else None,
                 round(max(angles), 1) if angles else None)


def summarise(robot: RobotReport) -> None:
    """Fill in the robot's shares over the columns it performs."""
    robot.arms = share(robot.keyframes, [c for c in ARM_COLUMNS if c in robot.performs])
    robot.head = share(robot.keyframes, [c for c in ("head",) if c in robot.performs])


def share_words(s: Share | None) -> str:
    if s is None:
        return "none written"
    angles = ("" if s.median_angle_deg is None
              else f", angle to the score median {s.median_angle_deg:g}°, worst "
              f"{s.worst_angle_deg:g}°")
    return f"{s.as_written}/{s.cells} notated back as written ({100 * s.share:.0f}%){angles}"


def write(report: ScoreReport, path: Path) -> None:
    """The report as JSON, written whole (to a temporary file renamed over ``path``), so a
    reader never sees half of one."""
    tmp = path.with_name(f".{path.name}.tmp")
    tmp.write_bytes(msgspec.json.format(msgspec.json.encode(report), indent=1))
    tmp.replace(path)


def robot_line(r: RobotReport) -> str:
    """One robot's performance in a line: the arms and head shares, how late, what failed."""
    words = [f"arms {share_words(r.arms)}" if r.arms or not any(
        c in r.performs for c in ARM_COLUMNS) else "arms: none performed"]
    if "head" in r.performs:
        words.append(f"head {share_words(r.head)}")
    else:
        words.append(f"head not performed ({r.skipped.get('head', 'no head')})")
    late = [k.late_ms for k in r.keyframes if k.late_ms > 0]
    if late:
        words.append(f"late at {len(late)} of {len(r.keyframes)} keyframes (worst "
                     f"{max(late)} ms)")
    else:
        words.append(f"on time at all {len(r.keyframes)} keyframes")
    refused = sum(1 for k in r.keyframes for c in k.cells
                  if not c.performed and c.column in r.performs)
    if refused:
        words.append(f"{refused} cell(s) not performed (see the check above)")
    if not r.turns and any(k.turn_deg for k in r.keyframes):
        words.append("rotation not performed (a fixed base)")
    said = [k for k in r.keyframes if k.said]
    if said:
        words.append(f"{said[0].keyframe}: {said[0].said}")
    return f"{r.robot} ({r.platform}): " + "; ".join(words)
