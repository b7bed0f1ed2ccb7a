"""Record a gamepad session as JSON lines and replay it, so a scenario can be rerun exactly.

What is recorded is the device-independent :class:`ControllerState` of every tick with its
time since the start, not raw pygame events: a replay then needs no pygame, no window and no
pad, and gives the same commands whatever controller made the recording. The first line is a
header (``{"kinesphere": "gamepad-recording", "version": 1, ...}``), each further line
``{"t": seconds, "state": {...}}``.

A replay follows its own clock: each ``poll`` returns the newest recorded snapshot whose time
has come, with the presses of every snapshot it skipped (a tap is never lost to a slower
replay). When the recording ends, the replay reports a neutral, released controller.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import IO, Any

from kinesphere.clients.state import NEUTRAL, ControllerState
from kinesphere.errors import KinesphereError

MAGIC = "gamepad-recording"
VERSION = 1


class Recorder:
    """Appends ticks to a JSON-lines file; use as a context manager or call :meth:`close`."""

    def __init__(self, path: str | Path, **header: Any) -> None:
        self.path = Path(path)
        try:
            self._f: IO[str] = self.path.open("w", encoding="utf-8")
        except OSError as exc:
            raise KinesphereError(
                "malformed", f"cannot write recording {path}: {exc.strerror}"
            ) from None
        self._write({"kinesphere": MAGIC, "version": VERSION, **header})

    def _write(self, obj: dict[str, Any]) -> None:
        self._f.write(json.dumps(obj, separators=(",", ":")) + "\n")

    def __call__(self, t: float, cs: ControllerState) -> None:
        self._write({"t": round(t, 4), "state": cs.to_dict()})

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


def load(path: str | Path) -> tuple[dict[str, Any], list[tuple[float, ControllerState]]]:
    """Header and ``(t, state)`` ticks of a recording, checked line by line."""
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise KinesphereError(
            "malformed", f"cannot read recording {path}: {exc.strerror}"
        ) from None
    if not lines:
        raise KinesphereError("malformed", f"recording {path} is empty")
    where = "header"
    try:
        header = json.loads(lines[0])
        if header.get("kinesphere") != MAGIC:
            raise ValueError("no gamepad-recording header")
        if header.get("version") != VERSION:
            raise ValueError(f"version {header.get('version')!r}, this client reads {VERSION}")
        ticks = []
        for n, line in enumerate(lines[1:], start=2):
            where = f"line {n}"
            if line.strip():
                obj = json.loads(line)
                ticks.append((float(obj["t"]), ControllerState.from_dict(obj["state"])))
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise KinesphereError("malformed", f"recording {path} {where}: {exc}") from None
    return header, ticks


class Replay:
    """A :class:`~kinesphere.clients.teleop.Source` that plays a recording back in time."""

    def __init__(
        self,
        ticks: list[tuple[float, ControllerState]],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.ticks = sorted(ticks, key=lambda tick: tick[0])
        self.clock = clock
        self._start: float | None = None
        self._i = 0
        self._current = NEUTRAL
        self._t0 = self.ticks[0][0] if self.ticks else 0.0  # replay starts at the first tick

    @classmethod
    def from_file(cls, path: str | Path, clock: Callable[[], float] = time.monotonic) -> Replay:
        return cls(load(path)[1], clock)

    @property
    def finished(self) -> bool:
        return self._i >= len(self.ticks)

    def poll(self) -> ControllerState:
        now = self.clock()
        if self._start is None:
            self._start = now
        elapsed = now - self._start
        pressed: set[str] = set()
        while self._i < len(self.ticks) and self.ticks[self._i][0] - self._t0 <= elapsed:
            self._current = self.ticks[self._i][1]
            pressed |= self._current.pressed
            self._i += 1
        if self.finished and self.ticks:
            self._current = NEUTRAL
        self._t0 = self.ticks[0][0] if self.ticks else 0.0  # replay starts at the first tick
        state = self._current.without_presses()
        return replace(state, pressed=frozenset(pressed), source="replay")
