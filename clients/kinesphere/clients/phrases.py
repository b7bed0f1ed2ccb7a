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
fresh commands arrive, and the robots' TTL stops them if this process dies mid-phrase.
"""

from __future__ import annotations

import time
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from kinesphere.clients.link import RobotLink, Sequencer
from kinesphere.clients.options import TeleopOptions
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.protocol import Drive, SpatialCommand
from kinesphere.sizes import parse_size

PHRASE_KEYS = ("name", "description", "ttl_ms", "step")
STEP_KEYS = ("duration", "parts", "drive", "note")


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


def parse_part(value: Any, where: str) -> SpatialCommand:
    """``"LIMB ORIGIN DIRECTION SIZE"`` or a table with those keys."""
    if isinstance(value, str):
        words = value.split()
        if len(words) != 4:
            raise KinesphereError(
                "malformed", f"{where}: {value!r} is not 'LIMB ORIGIN DIRECTION SIZE'"
            )
        limb, origin, direction, size = words
    elif isinstance(value, dict):
        unknown = set(value) - {"limb", "origin", "direction", "size"}
        missing = {"limb", "origin", "direction", "size"} - set(value)
        if unknown or missing:
            raise KinesphereError(
                "malformed",
                f"{where}: a part needs limb, origin, direction, size"
                + (f"; unknown {sorted(unknown)}" if unknown else "")
                + (f"; missing {sorted(missing)}" if missing else ""),
            )
        limb, origin, direction, size = (value[k] for k in ("limb", "origin", "direction", "size"))
    else:
        raise KinesphereError("malformed", f"{where}: a part is a string or a table")
    for what, text in (("limb", limb), ("origin", origin)):
        if not isinstance(text, str) or not text.strip():
            raise KinesphereError("malformed", f"{where}: {what} must be a non-empty string")
    return SpatialCommand(
        limb=limb, origin=origin, direction=Direction.parse(direction).slug, size=parse_size(size)
    )


def parse_drive(value: Any, where: str) -> Drive:
    """``"DIRECTION SPEED"`` or ``{direction, speed}``; a middle horizontal, speed 0..1."""
    if isinstance(value, str) and len(value.split()) == 2:
        direction, speed = value.split()
    elif isinstance(value, dict) and set(value) == {"direction", "speed"}:
        direction, speed = value["direction"], value["speed"]
    else:
        raise KinesphereError("malformed", f"{where}: drive is 'DIRECTION SPEED' or a table")
    return make_drive(direction, speed, where)


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
    unknown = set(data) - set(PHRASE_KEYS)
    if unknown:
        raise KinesphereError(
            "malformed", f"{source}: unknown {sorted(unknown)}; valid: {', '.join(PHRASE_KEYS)}"
        )
    raw = data.get("step")
    if not isinstance(raw, list) or not raw:
        raise KinesphereError("malformed", f"{source}: a phrase needs at least one [[step]]")
    steps = []
    for i, st in enumerate(raw, start=1):
        where = f"{source} step {i}"
        bad = set(st) - set(STEP_KEYS)
        if bad:
            raise KinesphereError(
                "malformed", f"{where}: unknown {sorted(bad)}; valid: {', '.join(STEP_KEYS)}"
            )
        dur = st.get("duration")
        if isinstance(dur, bool) or not isinstance(dur, (int, float)) or not 0 < dur <= 600:
            raise KinesphereError("malformed", f"{where}: duration must be 0 < s <= 600")
        parts = tuple(parse_part(p, where) for p in st.get("parts", []))
        drive = parse_drive(st["drive"], where) if "drive" in st else None
        if not parts and drive is None:
            raise KinesphereError("malformed", f"{where}: needs parts, a drive, or both")
        steps.append(Step(float(dur), parts, drive, str(st.get("note", ""))))
    ttl = data.get("ttl_ms")
    if ttl is not None and (isinstance(ttl, bool) or not isinstance(ttl, int) or ttl < 0):
        raise KinesphereError("malformed", f"{source}: ttl_ms must be an integer >= 0")
    name = str(data.get("name", Path(source).stem))
    return Phrase(name, tuple(steps), str(data.get("description", "")), ttl)


def shipped() -> list[str]:
    """Names of the phrases that come with the client."""
    root = resources.files("kinesphere.clients").joinpath("phrases")
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
                "malformed", f"no phrase file {ref}; shipped phrases: {', '.join(shipped())}"
            )
        res = resources.files("kinesphere.clients").joinpath(f"phrases/{name}.toml")
        text, source = res.read_text(encoding="utf-8"), f"{name}.toml"
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise KinesphereError("malformed", f"{source} is not TOML: {exc}") from None
    return parse_phrase(data, source)


def play(
    link: RobotLink,
    phrase: Phrase,
    keys: Sequence[str],
    seq: Sequencer,
    *,
    rate_hz: float = TeleopOptions.rate_hz,
    on_step: Callable[[int, Step], None] | None = None,
    should_stop: Callable[[], bool] = lambda: False,
) -> int:
    """Stream each step for its duration, then a final stop; returns commands sent.

    Steps start on absolute deadlines, so a phrase takes its written duration however long
    each put takes. The final stop also goes out when ``should_stop()`` ends it early.
    """
    period = 1.0 / rate_hz
    sent = 0
    t = time.monotonic()
    try:
        for i, step in enumerate(phrase.steps):
            if on_step is not None:
                on_step(i, step)
            end = t + step.duration
            while (now := time.monotonic()) < end and not should_stop():
                link.put(keys, seq.command(step.parts, step.drive, deadman=True))
                sent += 1
                t_next = min(end, now + period)
                time.sleep(max(0.0, t_next - time.monotonic()))
            if should_stop():
                break
            t = end
    finally:
        link.put(keys, seq.stop())
    return sent + 1
