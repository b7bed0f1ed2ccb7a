"""Which Labanotation cells a body can point a part into, from its URDF's joint limits alone.

Whether a score's cell is fair to ask of a body is decided here independently of the
generator (the ECL, its solver, its stored rows): the limb's joints are sampled uniformly
inside their limits (:func:`support.nested.reach`: a fixed seed, configurations where MuJoCo
finds the limb touching anything dropped), each segment's direction is measured by the same
URDF numbers yourdfpy reads, and written as a cell by LabanEditor's own ``coordinate2laban``.

* The outer segment (the upper arm: shoulder to elbow; the head) has a cell when some sample
  points it there. Baxter's upper arm cannot hang straight down (its ``s1`` stops at
  1.047 rad): it has no ``Place Low``.
* The inner segment (the forearm: elbow to the hand) is asked *with* the upper arm's cell
  (nested): it has a cell when some sample points the forearm there with the upper arm in its
  written cell, or, where the body has no such upper-arm cell, with the upper arm within 45°
  of the written direction (the nearest the body can hold it).

:func:`measured` tallies ``kinesphere play --report`` files by that rule, with yourdfpy's
kinematics of the joint states the robots reported and LabanEditor's notation; the test of
``play`` asserts on it, and the whole library's table in docs/labanotation.md was made with
it: ``cd tests && ../.venv/bin/python -m support.cells SCORE.json REPORT.json``.

The uniform sample is dense enough for the upper arm (it depends on two or three shoulder
joints); a forearm cell reachable only in a sliver of the arm's configuration space may be
missed, which only leaves that cell out of what a test asks.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from kinesphere.vocabulary import lookup, vocabulary
from support.nested import MeasuredBody, SegmentEnds, degrees, reach
from support.paths import LABAN_EDITOR

SAMPLES = 60000
NEAR = 45.0
"""Degrees: how far off its written direction an upper arm the body cannot put in its cell may
be held for the forearm's cell to be asked of it (the ECL's own bound for another movement)."""


def cell_names(laban_editor: ModuleType, vectors: np.ndarray) -> np.ndarray:
    """Each row's cell as LabanEditor writes it (``"Left Forward High"``), (n,) of str."""
    out = []
    for v in vectors:
        _, theta, phi = laban_editor.to_sphere(v)
        out.append(" ".join(laban_editor.coordinate2laban(theta, phi)))
    return np.array(out)


@dataclass(frozen=True)
class Reachable:
    """The cells one limb's two segments point into over its collision-free samples."""

    outer: np.ndarray
    """(n, 3) unit directions of the outer segment."""
    outer_cells: np.ndarray
    inner_cells: np.ndarray

    def has(self, cell: str) -> bool:
        """Whether the outer segment (upper arm, head) can point into ``cell``."""
        return bool(np.any(self.outer_cells == cell))

    def has_inner(self, outer: str, outer_direction: np.ndarray, inner: str) -> bool:
        """Whether the inner segment (forearm) can point into ``inner`` while the outer is
        in ``outer`` (or, when it cannot be, within :data:`NEAR` of ``outer_direction``)."""
        held = (self.outer_cells == outer if self.has(outer)
                else degrees(self.outer, outer_direction) <= NEAR)
        return bool(np.any(held & (self.inner_cells == inner)))

    def cells(self) -> set[str]:
        return set(self.outer_cells.tolist())


@cache
def reachable(platform: str, limb: str, outer: SegmentEnds, inner: SegmentEnds,
              laban_editor: ModuleType, samples: int = SAMPLES) -> Reachable:
    """What ``limb`` of ``platform`` can point ``outer`` and ``inner`` into (see the module);
    for a limb of one segment (a head) pass it twice."""
    r = reach(platform, limb, (outer, inner), samples=samples)
    return Reachable(r.first, cell_names(laban_editor, r.first),
                     cell_names(laban_editor, r.second))


PARTS = {"head": ("head", "neck"),
         "right elbow": ("right_upper_arm", "right_shoulder"),
         "right wrist": ("right_forearm", "right_elbow"),
         "left elbow": ("left_upper_arm", "left_shoulder"),
         "left wrist": ("left_forearm", "left_elbow")}
"""Score column -> the body words (limb, origin) of the part: the segment measured runs from
the origin's pivot to where the limb ends (the next location, or the limb's tip link)."""


def player_vector(direction: str, level: str) -> np.ndarray:
    """The score's direction as the suite's player draws it (labanotation.js: levels at 45,
    90, 135 degrees from the vertical, horizontals every 45 degrees; Place is vertical)."""
    if direction == "Place":
        return np.array([0.0, 0.0, 1.0 if level == "High" else -1.0])
    phi = np.radians({"Forward": 0, "Left Forward": 45, "Left": 90, "Left Backward": 135,
                      "Backward": 180, "Right Backward": -135, "Right": -90,
                      "Right Forward": -45}[direction])
    theta = np.radians({"High": 45, "Normal": 90, "Low": 135}[level])
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def segments(body: MeasuredBody) -> dict[str, SegmentEnds]:
    """Score column -> the segment the body's vocabulary names for it."""
    words = lookup(vocabulary(body.eurdf))
    out = {}
    for column, (limb, origin) in PARTS.items():
        if words[limb].label and words[origin].label:
            out[column] = SegmentEnds(words[origin].label, words[limb].end or words[limb].label)
    return out


def side_of(column: str) -> str:
    return column.split()[0]




@dataclass
class Tally:
    """One robot's cells over the keyframes played: every arm cell and how many came back as
    written; those the body can point its part into (:mod:`support.cells`, from its URDF
    alone), how many of them came back as written (a late or blocked keyframe counts, measured
    where the robot was) and their angles to the score's direction; the head's the same way."""

    performs: list[str] = field(default_factory=list)
    cells: int = 0
    same: int = 0
    reachable: int = 0
    same_reachable: int = 0
    angles: list[float] = field(default_factory=list)
    late: int = 0
    worst_late_ms: int = 0
    keyframes: int = 0
    unmeasured: int = 0
    head_reachable: int = 0
    head_same: int = 0

    def line(self, platform: str) -> str:
        return (f"{platform}: {self.same} of {self.cells} arm cells notated back as written; "
                f"{self.reachable} the body can reach, {self.same_reachable} of them as "
                f"written, {sum(a <= NEAR for a in self.angles)} within {NEAR:g} degrees "
                f"(worst {max(self.angles, default=0):.0f}); late at "
                f"{self.late} of {self.keyframes} keyframes (worst {self.worst_late_ms} ms), "
                f"{self.unmeasured} without a state; head {self.head_same} of "
                f"{self.head_reachable} reachable cells as written")


def measured(reports: list[dict[str, Any]], written: dict[str, dict[str, dict[str, list[str]]]],
             laban_editor: ModuleType, by: str = "robot") -> dict[str, Tally]:
    """Every robot's :class:`Tally` from ``--report`` files (the joint states it reported),
    by yourdfpy and LabanEditor, against the scores as ``json`` read them; a keyframe with no
    state reported counts its cells as not written. ``by="platform"`` adds up the robots of
    one platform (each played a different score)."""
    out: dict[str, Tally] = {}
    bodies: dict[str, tuple[MeasuredBody, dict[str, SegmentEnds]]] = {}
    for report in reports:
        for robot in report["robots"]:
            if robot["platform"] not in bodies:
                body = MeasuredBody(robot["platform"])
                bodies[robot["platform"]] = (body, segments(body))
            body, parts = bodies[robot["platform"]]
            t = out.setdefault(robot[by], Tally())
            t.performs = [c for c in robot["performs"] if c in parts and c != "head"]
            for kf in robot["keyframes"]:
                raw = written[kf["gesture"]][kf["keyframe"]]
                t.keyframes += 1
                t.late += kf["late_ms"] > 0
                t.worst_late_ms = max(t.worst_late_ms, kf["late_ms"])
                t.unmeasured += not kf["q"]
                if kf["q"]:
                    body.pose(dict(zip(kf["joint_names"], kf["q"], strict=True)))
                for column in [*t.performs, *(["head"] if "head" in parts else [])]:
                    cell = tuple(raw[column])
                    if cell == ("Place", "Normal"):
                        continue  # no direction: LabanEditor never writes it
                    v = body.direction(parts[column]) if kf["q"] else None
                    as_written = v is not None and tuple(laban_editor.coordinate2laban(
                        *laban_editor.to_sphere(v)[1:])) == cell  # no state: not as written
                    can = can_reach(body, parts, laban_editor, raw, column)
                    if column == "head":
                        t.head_reachable += can
                        t.head_same += can and as_written
                        continue
                    t.cells += 1
                    t.same += as_written
                    if can:
                        t.reachable += 1
                        t.same_reachable += as_written
                        t.angles.append(180.0 if v is None
                                        else float(degrees(v, player_vector(*cell))))
    return out


def can_reach(body: MeasuredBody, parts: dict[str, SegmentEnds], laban_editor: ModuleType,
              raw: dict[str, list[str]], column: str) -> bool:
    """Whether the body can point ``column``'s part into the score's cell (its joint limits,
    touching nothing: :mod:`support.cells`); a forearm with its upper arm as written."""
    side = side_of(column)
    outer = "head" if column == "head" else f"{side} elbow"
    inner = "head" if column == "head" else f"{side} wrist"
    limb = lookup(vocabulary(body.eurdf))["head" if column == "head" else f"{side}_arm"].label
    cells = reachable(body.platform.name, limb, parts[outer], parts[inner], laban_editor)
    if column == outer:
        return cells.has(" ".join(raw[column]))
    return cells.has_inner(" ".join(raw[outer]), player_vector(*raw[outer]),
                           " ".join(raw[column]))


def load_laban_editor() -> ModuleType:
    """LabanEditor's ``labanProcessor.py`` (vendored unchanged) loaded as a module."""
    spec = importlib.util.spec_from_file_location("labanProcessor", LABAN_EDITOR)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main(argv: Sequence[str]) -> int:
    """``python -m support.cells SCORE.json REPORT.json...``: one line per robot."""
    if len(argv) < 2:
        print("usage: python -m support.cells SCORE.json REPORT.json...", file=sys.stderr)
        return 2
    written = json.loads(Path(argv[0]).read_text())
    reports = [json.loads(Path(a).read_text()) for a in argv[1:]]
    platforms = {r["robot"]: r["platform"] for report in reports for r in report["robots"]}
    for robot, t in measured(reports, written, load_laban_editor()).items():
        print(f"{robot}: {t.line(platforms[robot])}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
