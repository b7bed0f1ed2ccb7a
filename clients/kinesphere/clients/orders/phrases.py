"""Movement phrases: a list of steps, each a set of spatial commands held for a duration.

A phrase file is TOML::

    name = "sweep"
    description = "..."
    ttl_ms = 300                # optional, robots hold if the stream stops for this long
    [[step]]
    duration = 2.0              # seconds this step is streamed
    parts = ["arm shoulder left-low far"]      # "LIMB ORIGIN DIRECTION SIZE", or tables:
    # parts = [{limb = "arm", origin = "shoulder", direction = "left-low", size = 3}]
    drive = "forward 0.3"       # optional: "DIRECTION SPEED" or {direction, speed}

Limbs and origins may be labels (``limb_11``) or human aliases (``right_arm``); aliases pass
through untouched and each robot's databank resolves them for its own body, which is what
lets one phrase play on different platforms. Directions and sizes are checked here (they are
the same vocabulary everywhere) so a typo fails before anything moves.

Each step is streamed at the loop rate rather than sent once: a drive lasts only as long as
fresh commands arrive, and the robots' TTL stops them if this process dies mid-phrase. The
last step goes on until the robots are there (``play``'s ``arrived``), so a phrase ends with
its robots at rest where it says. Before anything moves, ``kinesphere play`` asks each
target platform's databank for every step (:func:`unservable`): a phrase a body cannot play
fails at once instead of being refused command after command.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

import msgspec

from kinesphere.clients.link import RobotLink, Sequencer
from kinesphere.clients.options import TeleopOptions
from kinesphere.configfile import convert, parse_toml
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.protocol import MAX_NAME, MAX_TTL_MS, Drive, SpatialCommand
from kinesphere.sizes import parse_size

Label = Annotated[str, msgspec.Meta(min_length=1, max_length=MAX_NAME)]
ARRIVE_S = 10.0
"""How long a phrase's last step may go on after its time for the robots to get there."""


# --- the file as written (checked by msgspec) ----------------------------------------------


class _PartTable(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    limb: Label
    origin: Label
    direction: str
    size: float | str


class _DriveTable(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    direction: str
    speed: float


class _StepTable(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    duration: Annotated[float, msgspec.Meta(gt=0, le=600, description="0 < s <= 600 seconds")]
    parts: list[str | _PartTable] = []
    drive: str | _DriveTable | None = None
    note: str = ""

    def __post_init__(self) -> None:
        if not self.parts and self.drive is None:
            raise ValueError("needs parts, a drive, or both")


class _PhraseFile(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    step: Annotated[
        list[_StepTable], msgspec.Meta(min_length=1, description="at least one [[step]]")
    ]
    name: str | None = None
    description: str = ""
    ttl_ms: Annotated[int, msgspec.Meta(ge=0, le=MAX_TTL_MS)] | None = None


# --- what the client plays -----------------------------------------------------------------


@dataclass(frozen=True)
class Step:
    duration: float
    parts: tuple[SpatialCommand, ...]
    drive: Drive | None = None
    note: str = ""


@dataclass(frozen=True)
class Phrase:
    name: str
    steps: tuple[Step, ...]
    description: str = ""
    ttl_ms: int | None = None

    @property
    def duration(self) -> float:
        return sum(s.duration for s in self.steps)


def parse_part(value: str | _PartTable, where: str) -> SpatialCommand:
    """``"LIMB ORIGIN DIRECTION SIZE"`` or a part table; direction and size are checked."""
    if isinstance(value, str):
        words = value.split()
        if len(words) != 4:
            raise KinesphereError(
                "malformed", f"{where}: {value!r} is not 'LIMB ORIGIN DIRECTION SIZE'"
            )
        limb, origin, direction, size = words
        value = _PartTable(limb, origin, direction, size)
    return SpatialCommand(
        limb=value.limb,
        origin=value.origin,
        direction=Direction.parse(value.direction).slug,
        size=parse_size(value.size),
    )


def parse_drive(value: str | _DriveTable, where: str) -> Drive:
    """``"DIRECTION SPEED"`` or a drive table; a middle horizontal, speed 0..1."""
    if isinstance(value, str):
        if len(value.split()) != 2:
            raise KinesphereError("malformed", f"{where}: drive is 'DIRECTION SPEED' or a table")
        direction, speed = value.split()
        return make_drive(direction, speed, where)
    return make_drive(value.direction, value.speed, where)


def make_drive(direction: Any, speed: Any, where: str = "drive") -> Drive:
    d = Direction.parse(direction)
    if not d.is_translation:
        valid = ", ".join(t.slug for t in Direction.translations())
        raise KinesphereError(
            "unknown_direction", f"{where}: the base drives along {valid}; not {d.slug}"
        )
    try:
        s = float(speed)
    except (TypeError, ValueError):
        s = float("nan")
    if not 0.0 <= s <= 1.0:
        raise KinesphereError("malformed", f"{where}: speed must be 0..1, got {speed!r}")
    return Drive(direction=d.slug, speed=s)


def parse_phrase(data: dict[str, Any], source: str) -> Phrase:
    """A phrase from TOML data: the schema by msgspec, then labels' vocabulary per step."""
    f = convert(data, _PhraseFile, source, name_lists=True)
    steps = []
    for i, st in enumerate(f.step, start=1):
        where = f"{source} step {i}"
        parts = tuple(parse_part(p, where) for p in st.parts)
        drive = parse_drive(st.drive, where) if st.drive is not None else None
        steps.append(Step(st.duration, parts, drive, st.note))
    name = f.name if f.name is not None else Path(source).stem
    return Phrase(name, tuple(steps), f.description, f.ttl_ms)


def shipped() -> list[str]:
    """Names of the phrases that come with the client."""
    root = resources.files("kinesphere.clients.orders").joinpath("phrases")
    return sorted(p.name[: -len(".toml")] for p in root.iterdir() if p.name.endswith(".toml"))


def load_phrase(ref: str | Path) -> Phrase:
    """A phrase from a file path, or a shipped phrase by name (``sweep`` or ``sweep.toml``)."""
    path = Path(ref)
    if path.is_file():
        text, source = path.read_text(encoding="utf-8"), str(path)
    else:
        name = path.name[: -len(".toml")] if path.name.endswith(".toml") else path.name
        if path.parent != Path(".") or name not in shipped():
            raise KinesphereError(
                "not_found", f"no phrase file {ref}; shipped phrases: {', '.join(shipped())}"
            )
        res = resources.files("kinesphere.clients.orders").joinpath(f"phrases/{name}.toml")
        text, source = res.read_text(encoding="utf-8"), f"{name}.toml"
    data = parse_toml(text, source)
    return parse_phrase(data, source)


def unservable(link: RobotLink, phrase: Phrase, platforms: Mapping[str, str],
               timeout: float = 2.0) -> tuple[dict[str, str], list[str]]:
    """Robots (id -> platform) that cannot play ``phrase``, each with why: the first step
    whose parts its databank refuses (an unknown limb or origin, a direction it has nothing
    near, a part the body lacks), asked before anything moves; and the platforms that could
    not be checked (no databank answered: their robots resolve the phrase themselves).
    Substitutions are fine: the robot serves them. Each step is asked once per platform."""
    why: dict[str, str] = {}
    unchecked: list[str] = []
    for platform in sorted(set(platforms.values())):
        problem = ""
        for i, step in enumerate(phrase.steps, start=1):
            if not step.parts:
                continue
            try:
                link.pose(platform, step.parts, timeout)
            except KinesphereError as exc:
                if exc.code == "unavailable":
                    unchecked.append(platform)
                    break
                said = " + ".join(f"{p.limb} {p.origin} {p.direction} {p.size:g}"
                                  for p in step.parts)
                problem = f"step {i} ({said}): {exc.code}: {exc.message}"
                break
        for rid, p in platforms.items():
            if p == platform and problem:
                why[rid] = problem
    return why, unchecked


def play(
    link: RobotLink,
    phrase: Phrase,
    keys: Sequence[str],
    seq: Sequencer,
    *,
    rate_hz: float = TeleopOptions.rate_hz,
    on_step: Callable[[int, Step], None] | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    arrived: Callable[[int], bool] | None = None,
    arrive_s: float = ARRIVE_S,
) -> int:
    """Stream each step for its duration, then a final stop; returns commands sent.

    Steps start on absolute deadlines, so a phrase takes its written duration however long
    each put takes. When the last step moves limbs and ``arrived`` is given, it goes on
    streaming (without its drive) until ``arrived(first seq of the last step)`` says every
    robot finished that motion (reached, clamped, blocked, refused), at most ``arrive_s``
    more: the phrase ends where it says, not wherever the robots were when its time ran
    out. The final stop also goes out when ``should_stop()`` ends it early.
    """
    period = 1.0 / rate_hz
    sent = 0
    t = time.monotonic()
    last_from = seq.seq
    try:
        for i, step in enumerate(phrase.steps):
            if on_step is not None:
                on_step(i, step)
            end = t + step.duration
            last_from = seq.seq
            while (now := time.monotonic()) < end and not should_stop():
                link.put(keys, seq.command(step.parts, step.drive, deadman=True))
                sent += 1
                t_next = min(end, now + period)
                time.sleep(max(0.0, t_next - time.monotonic()))
            if should_stop():
                break
            t = end
        last = phrase.steps[-1]
        if arrived is not None and last.parts and not should_stop():
            end = time.monotonic() + arrive_s
            while time.monotonic() < end and not should_stop() and not arrived(last_from):
                link.put(keys, seq.command(last.parts, None, deadman=True))
                sent += 1
                time.sleep(period)
    finally:
        link.put(keys, seq.let_go())
    return sent + 1
