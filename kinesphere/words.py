"""Commands in words, for people watching robots: ``right_arm ← right_shoulder → left-high, far``.

The view, recordings and films caption what a robot was told in the paper's language. Labels
are shown by their aliases when the body has them (``limb_11`` is ``right_arm`` on Baxter), so
one command reads naturally on every body.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

from kinesphere.protocol import BodyWord, Command, Drive, SpatialCommand
from kinesphere.sizes import size_name


def degrees(angle_rad: float) -> str:
    """An angle for people: ``+12°``, never ``-0°``."""
    return f"{round(math.degrees(angle_rad)) + 0:+d}°"


def signed(value: float, digits: int = 2) -> str:
    """A signed number for people: ``+1.20``, never ``-0.00``."""
    return f"{round(value, digits) + 0.0:+.{digits}f}"


def label_names(aliases: Mapping[str, str]) -> dict[str, str]:
    """label -> alias, from an eURDF's or catalogue's alias -> label map."""
    return {label: alias for alias, label in sorted(aliases.items())}


def part_words(part: SpatialCommand, names: Mapping[str, str] | None = None) -> str:
    """``limb ← origin → direction, size`` with labels shown by ``names`` (label -> alias)."""
    names = names or {}
    limb = names.get(part.limb, part.limb)
    origin = names.get(part.origin, part.origin)
    exact = " (exact)" if part.exact else ""
    return f"{limb} ← {origin} → {part.direction}, {size_name(part.size)}{exact}"


def drive_words(drive: Drive) -> str:
    """``drive forward-middle 0.50`` or ``drive forward +0.50 left -0.20 yaw +0.10``."""
    if drive.is_continuous:
        return (f"drive forward {drive.forward:+.2f} left {drive.left:+.2f} "
                f"yaw {drive.yaw:+.2f}")
    return f"drive {drive.direction} {drive.speed:.2f}"


def command_words(cmd: Command, names: Mapping[str, str] | None = None) -> str:
    """What a command asks, in one line (e-stop, release, stop and let-go first)."""
    if cmd.estop:
        return "E-STOP"
    if cmd.release:
        return "release the e-stop"
    if cmd.stop:
        return "stop"
    if not cmd.deadman:
        return "let go: hold"
    words = [part_words(p, names) for p in cmd.parts]
    if cmd.drive is not None:
        words.append(drive_words(cmd.drive))
    return " + ".join(words) or (f"lease {cmd.lease}" if cmd.lease else "nothing")


def body_words(said: Iterable[BodyWord]) -> str:
    """How a body answered body-vocabulary words: ``right_arm -> limb_11 (the only arm)``,
    ``right_upper_arm -> limb_11 up to distal_12 (the right arm up to right_elbow)``."""
    out = []
    for w in said:
        end = f" up to {w.end}" if w.end else ""
        note = f" ({w.note})" if w.note else ""
        out.append(f"{w.word} -> {w.label or 'nothing'}{end}{note}")
    return ", ".join(out)
