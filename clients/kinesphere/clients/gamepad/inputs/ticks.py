"""Record a gamepad session to MCAP and replay it, so a scenario can be rerun exactly.

What is recorded is the device-independent :class:`ControllerState` of every tick, not raw
pygame events: a replay then needs no pygame, no window and no pad, and gives the same
commands whatever controller made the recording. The file is MCAP like every other recording
of kinesphere (``kinesphere record``): one channel, :data:`TOPIC`, schema
``kinesphere.ControllerState`` (JSON Schema, JSON messages, so Foxglove and the ``mcap`` CLI
read it), each message's ``log_time`` the tick's time; the ``kinesphere`` metadata record
names the format (``{"kinesphere": "gamepad-recording", "version": "2", ...}``) and carries
the header (target, rate, mapping) as JSON values.

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
from typing import Any, Final

from kinesphere import hints
from kinesphere.clients import mcaplog
from kinesphere.clients.gamepad.state import NEUTRAL, ControllerState
from kinesphere.closing import Closable
from kinesphere.errors import KinesphereError

MAGIC: Final = mcaplog.GAMEPAD_RECORDING
VERSION: Final = 2
"""2: MCAP (1 was JSON lines)."""
TOPIC: Final = "gamepad/state"
SCHEMA: Final = f"{mcaplog.SCHEMA_PREFIX}{ControllerState.__name__}"


class TickRecorder(Closable):
    """Appends ticks to an MCAP file; use as a context manager or call :meth:`close`."""

    def __init__(self, path: str | Path, **header: Any) -> None:
        self._start_ns = time.time_ns()
        meta = {k: json.dumps(v) for k, v in header.items()}
        meta.update(kinesphere=MAGIC, version=str(VERSION), start_ns=str(self._start_ns))
        self._w = mcaplog.McapWriter(path, meta)

    def __call__(self, t: float, cs: ControllerState) -> None:
        data = json.dumps(cs.to_dict(), separators=(",", ":")).encode()
        self._w.write_json(TOPIC, ControllerState, data, self._start_ns + round(t * 1e9))

    def close(self) -> None:
        self._w.close()


def save(path: str | Path, ticks: list[tuple[float, ControllerState]], **header: Any) -> None:
    """Write ``(t, state)`` ticks as a recording (scenarios made by hand, tests)."""
    with TickRecorder(path, **header) as rec:
        for t, cs in ticks:
            rec(t, cs)


def load(path: str | Path) -> tuple[dict[str, Any], list[tuple[float, ControllerState]]]:
    """Header and ``(t, state)`` ticks of a recording, checked message by message."""
    try:
        Path(path).open("rb").close()
    except OSError as exc:
        raise KinesphereError(
            "malformed", f"cannot read recording {path}: {exc.strerror}"
        ) from None
    meta = mcaplog.metadata(path)
    if meta.get("kinesphere") != MAGIC:
        what = (f"it is a session of messages: put them back with '{hints.replay(str(path))}'"
                if "prefix" in meta else "a gamepad records one with --record FILE")
        raise KinesphereError("malformed", f"recording {path} has no gamepad-recording header "
                              f"({what})")
    if meta.get("version") != str(VERSION):
        raise KinesphereError("malformed", f"recording {path}: version {meta.get('version')!r}, "
                              f"this client reads {VERSION}")
    try:
        start_ns = int(meta["start_ns"])
        header: dict[str, Any] = {k: json.loads(v) for k, v in meta.items()
                                  if k not in ("kinesphere", "version", "start_ns")}
    except (KeyError, ValueError) as exc:
        raise KinesphereError("malformed", f"recording {path} header: {exc}") from None
    header.update(kinesphere=MAGIC, version=VERSION)
    ticks = []
    for n, m in enumerate(mcaplog.messages(path, SCHEMA), start=1):
        try:
            state = json.loads(m.data)
            if not isinstance(state, dict):
                raise TypeError(f"a state is an object, got {type(state).__name__}")
            ticks.append(((m.log_ns - start_ns) / 1e9, ControllerState.from_dict(state)))
        except (ValueError, TypeError) as exc:
            raise KinesphereError("malformed", f"recording {path} tick {n}: {exc}") from None
    return header, ticks


class TickReplay:
    """A :class:`~kinesphere.clients.gamepad.teleop.Source` that plays a recording back in time."""

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
    def from_file(cls, path: str | Path, clock: Callable[[], float] = time.monotonic) -> TickReplay:
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
