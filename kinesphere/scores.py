"""Labanotation scores as Microsoft's LabanotationSuite writes them (LabanEditor's JSON).

A score file holds gestures by name; a gesture holds keyframes (``Position0``, ``Position1``
...) in order, each with strings in lists::

    {"away": {"Position0": {"start time": ["1"], "duration": ["0"],
                            "head": ["Forward", "Normal"],
                            "right elbow": ["Place", "Low"], "right wrist": ["Place", "Low"],
                            "left elbow": ["Place", "Low"], "left wrist": ["Place", "Low"],
                            "rotation": ["ToRight", "0"]}, ...}}

``start time`` is when the keyframe's pose is reached, in milliseconds (the suite's player
interpolates from one keyframe's time to the next); ``duration`` is LabanEditor's bookkeeping
(0, or -1 on the last keyframe) and is checked but not used for timing. The columns are
:data:`COLUMNS`: the head, and per side the ``elbow`` (the upper arm, shoulder to elbow) and
the ``wrist`` (the forearm, elbow to wrist), each a :class:`~kinesphere.notation.Cell` in the
mover's body frame. ``rotation`` is the whole body's facing relative to the gesture's start
(``ToRight 60``: turned 60 degrees to the right; negative degrees turn the other way).

Everything is checked before anything moves, and bounded (file size, gestures, keyframes,
time): an unknown direction, level or part, a time that is negative, missing or not later
than the one before is ``malformed``, naming the gesture and the keyframe.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import msgspec

from kinesphere.errors import KinesphereError, did_you_mean
from kinesphere.notation import Cell

COLUMNS: Final = ("head", "right elbow", "right wrist", "left elbow", "left wrist")
"""The body parts a LabanotationSuite score writes a cell for, in its order."""
TIME_KEYS: Final = ("start time", "duration")
ROTATION_KEY: Final = "rotation"
KNOWN_KEYS: Final = (*TIME_KEYS, *COLUMNS, ROTATION_KEY)
TURNS: Final = {"ToLeft": 1.0, "ToRight": -1.0}
"""Rotation words and the sign of the turn they mean (left is counter-clockwise, positive)."""
MAX_SCORE_BYTES: Final = 1024 * 1024
"""Largest score file (the suite's largest gesture is 8 KB)."""
MAX_GESTURES: Final = 1000
MAX_KEYFRAMES: Final = 2000
"""Keyframes in one file, all gestures together (the suite's 92 gestures have 440)."""
MAX_TIME_MS: Final = 3_600_000
"""Latest start time: an hour."""
MAX_TURN_DEG: Final = 360.0


@dataclass(frozen=True)
class Keyframe:
    """One pose of a gesture: when it is reached, a cell per column, the body's facing."""

    index: int
    name: str
    time_ms: int
    cells: Mapping[str, Cell]
    """Column (:data:`COLUMNS`) -> its cell."""
    turn_deg: float = 0.0
    """The body's facing relative to the gesture's start, degrees, left positive."""
    duration: int = 0

    def notation(self) -> str:
        """The keyframe as a score writes it, one column after the other (captions)."""
        cells = "; ".join(f"{c}: {self.cells[c]}" for c in COLUMNS)
        turn = f"; rotation {_turn_words(self.turn_deg)}" if self.turn_deg else ""
        return f"{cells}{turn}"


@dataclass(frozen=True)
class Gesture:
    name: str
    keyframes: tuple[Keyframe, ...]

    @property
    def duration_ms(self) -> int:
        """From the first keyframe's time to the last's."""
        return self.keyframes[-1].time_ms - self.keyframes[0].time_ms


@dataclass(frozen=True)
class Score:
    source: str
    gestures: tuple[Gesture, ...]

    def gesture(self, name: str) -> Gesture:
        """The gesture called ``name``; ``malformed`` listing the score's gestures."""
        for g in self.gestures:
            if g.name == name:
                return g
        names = [g.name for g in self.gestures]
        raise KinesphereError(
            "malformed", f"{self.source} has no gesture {name!r}{did_you_mean(name, names)}; "
            f"its gestures: {', '.join(names)}")


def _turn_words(deg: float) -> str:
    return f"{'ToLeft' if deg > 0 else 'ToRight'} {abs(deg):g}"


Value = str | int | float
_FILE = dict[str, dict[str, dict[str, list[Value]]]]
_DECODER: Final = msgspec.json.Decoder(_FILE)


def _number(value: list[Value], where: str, what: str) -> float:
    if len(value) != 1 or isinstance(value[0], bool):
        raise KinesphereError("malformed", f"{where}: {what} must be one number, got "
                              f"{value!r:.80}")
    try:
        number = float(value[0])
    except ValueError:
        raise KinesphereError("malformed", f"{where}: {what} {value[0]!r:.40} is not a "
                              "number") from None
    if not math.isfinite(number):
        raise KinesphereError("malformed", f"{where}: {what} must be finite, got {number}")
    return number


def _keyframe(index: int, name: str, raw: Mapping[str, list[Value]], where: str,
              before: Keyframe | None) -> Keyframe:
    unknown = [k for k in raw if k not in KNOWN_KEYS]
    if unknown:
        raise KinesphereError(
            "malformed", f"{where}: unknown part {unknown[0]!r:.60}"
            f"{did_you_mean(unknown[0], KNOWN_KEYS)}; a keyframe has {', '.join(KNOWN_KEYS)}")
    missing = [k for k in ("start time", *COLUMNS) if k not in raw]
    if missing:
        raise KinesphereError("malformed", f"{where}: no {missing[0]!r} (a keyframe needs "
                              f"'start time' and {', '.join(map(repr, COLUMNS))})")
    t = _number(raw["start time"], where, "start time")
    if t != int(t) or not 0 <= t <= MAX_TIME_MS:
        raise KinesphereError("malformed", f"{where}: start time must be a whole number of "
                              f"milliseconds, 0..{MAX_TIME_MS}, got {t:g}")
    if before is not None and t <= before.time_ms:
        raise KinesphereError(
            "malformed", f"{where}: start time {t:g} ms is not later than {before.name}'s "
            f"{before.time_ms} ms (keyframes are reached in order)")
    duration = (_number(raw["duration"], where, "duration") if "duration" in raw else 0.0)
    if duration != int(duration) or not -1 <= duration <= MAX_TIME_MS:
        raise KinesphereError("malformed", f"{where}: duration must be a whole number of "
                              f"milliseconds, -1..{MAX_TIME_MS}, got {duration:g}")
    cells = {}
    for column in COLUMNS:
        value = raw[column]
        if len(value) != 2:
            raise KinesphereError("malformed", f"{where}: {column} must be [direction, level], "
                                  f"got {value!r:.80}")
        cells[column] = Cell.parse(value[0], value[1], f"{where} {column}")
    turn = 0.0
    if ROTATION_KEY in raw:
        value = raw[ROTATION_KEY]
        if len(value) != 2 or value[0] not in TURNS:
            raise KinesphereError("malformed", f"{where}: rotation must be [ToLeft|ToRight, "
                                  f"degrees], got {value!r:.80}")
        deg = _number(value[1:], where, "rotation")
        if not abs(deg) <= MAX_TURN_DEG:
            raise KinesphereError("malformed", f"{where}: rotation of {deg:g} degrees; at most "
                                  f"{MAX_TURN_DEG:g}")
        turn = TURNS[str(value[0])] * deg + 0.0  # no -0.0
    return Keyframe(index, name, int(t), cells, turn, int(duration))


def parse_score(data: bytes | str, source: str) -> Score:
    """A score from a file's bytes (see the module); ``malformed`` naming the keyframe."""
    raw_bytes = data.encode() if isinstance(data, str) else data
    if len(raw_bytes) > MAX_SCORE_BYTES:
        raise KinesphereError("malformed", f"{source}: {len(raw_bytes)} bytes; a score file "
                              f"has at most {MAX_SCORE_BYTES}")
    try:
        raw = _DECODER.decode(raw_bytes)
    except msgspec.ValidationError as exc:
        raise KinesphereError("malformed", f"{source} is not a LabanotationSuite score "
                              f"(gesture -> Position -> part -> [values]): {exc}") from None
    except msgspec.DecodeError as exc:
        raise KinesphereError("malformed", f"{source} is not JSON: {exc}") from None
    if not raw:
        raise KinesphereError("malformed", f"{source} holds no gesture")
    if len(raw) > MAX_GESTURES:
        raise KinesphereError("malformed", f"{source}: {len(raw)} gestures; at most "
                              f"{MAX_GESTURES}")
    total = sum(len(kfs) for kfs in raw.values())
    if total > MAX_KEYFRAMES:
        raise KinesphereError("malformed", f"{source}: {total} keyframes; a score has at most "
                              f"{MAX_KEYFRAMES}")
    gestures = []
    for gname, kfs in raw.items():
        if not kfs:
            raise KinesphereError("malformed", f"{source} gesture {gname!r:.60} has no keyframe")
        frames: list[Keyframe] = []
        for i, (kname, kraw) in enumerate(kfs.items()):
            where = f"{source} gesture {gname!r:.60} keyframe {kname!r:.60}"
            frames.append(_keyframe(i, kname, kraw, where, frames[-1] if frames else None))
        gestures.append(Gesture(gname, tuple(frames)))
    return Score(source, tuple(gestures))


def load_score(path: str | Path) -> Score:
    """A score file (bounded: its size is checked before it is read)."""
    p = Path(path)
    try:
        size = p.stat().st_size
        if size > MAX_SCORE_BYTES:
            raise KinesphereError("malformed", f"{p}: {size} bytes; a score file has at most "
                                  f"{MAX_SCORE_BYTES}")
        with p.open("rb") as f:
            data = f.read(MAX_SCORE_BYTES + 1)
    except OSError as exc:
        raise KinesphereError("malformed", f"cannot read score {p}: {exc.strerror}") from None
    return parse_score(data, p.name)
