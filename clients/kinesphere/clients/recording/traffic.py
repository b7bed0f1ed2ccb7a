"""``kinesphere record`` and ``kinesphere replay``: a session on Zenoh to MCAP and back.

The recorder records every kind of message kinesphere puts: commands (robot, all and group
keys), robot states, acks and the databank's ``changed`` poses. It decodes each (what does not
decode is counted, not recorded) and writes it on its own key's channel, in arrival order: one
subscriber takes everything under the prefix, because zenoh-python calls each subscriber back
on a thread of its own, and with one subscriber per kind a command and the state right after
it could be written (and replayed) the wrong way round. The file is bounded by ``max_bytes``.

A replay re-puts recorded messages on their keys with the original spacing (``speed`` scales
it): commands to drive robots again, or states to watch a session in ``kinesphere view``
without any robot running. It declares a publisher per key and waits until each has a
subscriber before the first put: a put made before the subscribers' declarations reached this
session goes nowhere, so the first messages of a replay would be lost. Commands go out as
recorded, with their sender, session, ``seq`` and ``sent_ns``: a robot that already heard that
session drops them as stale (that is its ordering rule, not a fault). ``restamp`` makes them
new: ``sent_ns`` becomes the time of the put, and each recorded session is replaced by a fresh
one (``seq`` and sender are kept, so the order within a session holds), which every robot takes
as a new order.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import msgspec
import zenoh

from kinesphere.clients.link import new_session
from kinesphere.clients.mcaplog import GAMEPAD_RECORDING, McapWriter, metadata, read
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import WILDCARD, Keys
from kinesphere.protocol import Command, Message, RobotState, decode_any, encode
from kinesphere.zconfig import undeclare, unmatched

log = logging.getLogger(__name__)
MAX_BYTES: Final = 1 << 30
KINDS: Final = ("commands", "states", "all")
WAIT_S: Final = 5.0
"""How long a replay waits for a subscriber on each recorded key before its first put."""


def tapped_keys(keys: Keys) -> list[str]:
    """Every key expression the recorder records."""
    return [Keys.subscribed(keys.command(WILDCARD)),
            Keys.subscribed(f"{keys.prefix}/group/*/command"), keys.state(WILDCARD),
            keys.ack(WILDCARD), keys.changed(WILDCARD)]


@dataclass
class Tally:
    recorded: int = 0
    undecodable: int = 0
    by_type: dict[str, int] = field(default_factory=dict)


class TrafficRecorder:
    """Records everything under ``keys.prefix`` into ``path`` until :meth:`close`."""

    def __init__(self, session: zenoh.Session, keys: Keys, path: str | Path,
                 max_bytes: int = MAX_BYTES) -> None:
        self.writer = McapWriter(path, {"prefix": keys.prefix})
        self.max_bytes = max_bytes
        self.tally = Tally()
        self.full = threading.Event()
        self._lock = threading.Lock()
        self._open = True
        self._taps = [zenoh.KeyExpr(k) for k in tapped_keys(keys)]
        self._sub: Any = session.declare_subscriber(f"{keys.prefix}/**", self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        now = time.time_ns()
        if not any(tap.intersects(sample.key_expr) for tap in self._taps):
            return
        try:
            msg = decode_any(sample.payload)
        except KinesphereError:
            with self._lock:
                self.tally.undecodable += 1
            return
        with self._lock:
            if not self._open or self.full.is_set():
                return
            self.writer.write(str(sample.key_expr), msg, now)
            t = self.tally
            t.recorded += 1
            name = type(msg).__name__
            t.by_type[name] = t.by_type.get(name, 0) + 1
            if self.writer.bytes >= self.max_bytes:
                self.full.set()

    def close(self) -> Tally:
        undeclare(self._sub)
        self._sub = None
        with self._lock:
            if self._open:
                self._open = False
                self.writer.close()
        return self.tally


def wanted(kind: str) -> Callable[[Message], bool]:
    """Which recorded messages a replay of ``kind`` puts back."""
    if kind == "commands":
        return lambda m: isinstance(m, Command)
    if kind == "states":
        return lambda m: isinstance(m, RobotState)
    if kind == "all":
        return lambda m: isinstance(m, (Command, RobotState))
    raise KinesphereError("malformed", f"replay {kind!r}? choose one of {', '.join(KINDS)}")


@dataclass(frozen=True)
class Replayed:
    """What a replay did: how many messages it put, and the recorded keys nobody subscribed
    to when it began (their messages went out to no one)."""

    sent: int
    unheard: list[str]


def replay(session: zenoh.Session, path: str | Path, kind: str = "commands",
           speed: float = 1.0, should_stop: Callable[[], bool] = lambda: False,
           on_put: Callable[[str, Message], None] | None = None, restamp: bool = False,
           wait: float = WAIT_S) -> Replayed:
    """Put the recording's ``kind`` messages back on their keys with the original timing
    (commands as new ones with ``restamp``), once each key has a subscriber or ``wait``
    seconds have passed; unavailable when no key has one by then."""
    if not speed > 0:
        raise KinesphereError("malformed", f"--speed must be > 0, got {speed}")
    if not wait >= 0:
        raise KinesphereError("malformed", f"--wait must be >= 0, got {wait}")
    keep = wanted(kind)
    items = [r for r in read(path) if keep(r.message)]
    if not items:
        if metadata(path).get("kinesphere") == GAMEPAD_RECORDING:
            raise KinesphereError(
                "malformed", f"{path} holds a gamepad's controller ticks, not messages: play "
                f"it with 'kinesphere gamepad --replay {path}'")
        return Replayed(0, [])
    publishers: dict[str, Any] = {}
    sessions: dict[tuple[str, str], str] = {}
    sent = 0
    try:
        for key in dict.fromkeys(r.key for r in items):
            publishers[key] = session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.BLOCK, express=True)
        unheard = unmatched(publishers, wait)
        if len(unheard) == len(publishers):
            raise KinesphereError("unavailable", f"nobody listens on {few(unheard)} (waited "
                                  f"{wait:g} s): nothing replayed")
        start, t0 = time.monotonic(), items[0].log_ns
        for rec in items:
            due = start + (rec.log_ns - t0) / 1e9 / speed
            while (left := due - time.monotonic()) > 0:
                if should_stop():
                    return Replayed(sent, unheard)
                time.sleep(min(left, 0.05))
            msg = rec.message
            if restamp and isinstance(msg, Command):
                msg = _restamped(msg, sessions)
            publishers[rec.key].put(encode(msg))
            sent += 1
            if on_put is not None:
                on_put(rec.key, msg)
    finally:
        undeclare(*publishers.values())
    return Replayed(sent, unheard)


def few(keys: list[str], most: int = 3) -> str:
    """``keys`` for a message: the first ``most`` and how many more."""
    more = f" and {len(keys) - most} more" if len(keys) > most else ""
    return ", ".join(keys[:most]) + more


def _restamped(cmd: Command, sessions: dict[tuple[str, str], str]) -> Command:
    """``cmd`` sent now, in a fresh session standing for its recorded one (a sender without a
    session keeps none: a later ``sent_ns`` is what makes its commands new)."""
    session = cmd.session
    if session:
        session = sessions.setdefault((cmd.sender, session), new_session())
    return msgspec.structs.replace(cmd, sent_ns=time.time_ns(), session=session)


def summary(tally: Tally, path: Path) -> str:
    kinds = ", ".join(f"{n} {t}" for t, n in sorted(tally.by_type.items()))
    bad = f"; {tally.undecodable} undecodable skipped" if tally.undecodable else ""
    return f"recorded {tally.recorded} messages to {path} ({kinds or 'none'}){bad}"


