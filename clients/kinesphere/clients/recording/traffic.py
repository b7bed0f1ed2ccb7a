"""``kinesphere record`` and ``kinesphere replay``: a session on Zenoh to MCAP and back.

The recorder records every kind of message kinesphere puts: commands (robot, all and group
keys), robot states, acks and the databank's ``changed`` poses. It decodes each (what does not
decode is counted, not recorded) and writes it on its own key's channel, in arrival order: one
subscriber takes everything under the prefix, because zenoh-python calls each subscriber back
on a thread of its own, and with one subscriber per kind a command and the state right after
it could be written (and replayed) the wrong way round. The file is bounded by ``max_bytes``.

A replay re-puts recorded messages on their keys with the original spacing (``speed`` scales
it): commands to drive robots again, or states to watch a session in ``kinesphere view``
without any robot running. A recording is any file someone hands over, so a replay first
surveys its channels (``mcaplog``, bounded) and refuses it, before
anything is put, when a command or state channel is not one of the project's own keys under
the replay's prefix (``{p}/robot/{id|*}/command[/sender]``, ``{p}/group/{g}/command[/sender]``,
``{p}/robot/{id}/state``): no ``**``, no databank key, nothing Zenoh cannot parse (the
channels come from the file's summary, so the first put does not wait for a pass over a long
file; a channel the summary leaves out is not replayed). Then it
streams the messages, so memory stays bounded whatever their number, and a silence in the
recording longer than ``max_gap`` is shortened to it. It declares a publisher per key and
waits until each has a subscriber before the first put: a put made before the subscribers'
declarations reached this session goes nowhere, so the first messages of a replay would be
lost. A match may be any subscriber (a recorder, a view on a peer hub, which routes for
nobody) while the link to the robot is still opening, so for a key naming a robot it also
waits for that robot's liveliness token (:func:`kinesphere.zconfig.unseen`). Commands go
out as recorded, with their sender, session, ``seq`` and ``sent_ns``, on their recorded
key: a robot that already heard that session drops them as stale (that is its ordering
rule, not a fault), and behind the deploy's access control only the recorded sender may put
them. ``restamp`` makes them the replaying operator's: sent now by ``sender`` on keys
signed with that name, each recorded session replaced by a fresh one (``seq`` kept, so the
order within a session holds), which every robot takes as a new order.

A replay of commands also listens to the robots' acks and counts what became of what it put
(:class:`Answers`): acted on, dropped as stale or expired, refused; after the last command it
waits a moment for the last answers. So ``kinesphere replay`` says when every robot dropped a
session it had already heard, names the ``--restamp`` replay that works, and exits non-zero.
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
from mcap.records import Channel, Metadata
from mcap.records import Schema as McapSchema

from kinesphere import hints
from kinesphere.clients.link import host_clock, new_session, operator_id
from kinesphere.clients.mcaplog import (
    BY_NAME,
    GAMEPAD_RECORDING,
    MAX_CHANNELS,
    McapWriter,
    decode_recorded,
    described,
    messages,
)
from kinesphere.clients.options import REPLAYED, TrafficOptions
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import WILDCARD, Keys
from kinesphere.lru import Lru
from kinesphere.protocol import (
    Ack,
    AckStage,
    Command,
    Message,
    RobotState,
    decode_any,
    encode,
)
from kinesphere.zconfig import undeclare, unmatched, unseen

log = logging.getLogger(__name__)
MAX_BYTES: Final = int(TrafficOptions.max_mb * 1e6)
KINDS: Final = REPLAYED
WAIT_S: Final = TrafficOptions.wait_s
"""How long a replay waits for a subscriber on each recorded key before its first put."""
MAX_GAP_S: Final = TrafficOptions.max_gap_s
"""The longest silence a replay keeps; longer ones are shortened to it."""
MAX_SESSIONS: Final = 1024
"""Recorded sessions a restamped replay keeps a fresh session for at once."""


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


def wanted(kind: str) -> tuple[type[Message], ...]:
    """Which recorded messages a replay of ``kind`` puts back."""
    if kind == "commands":
        return (Command,)
    if kind == "states":
        return (RobotState,)
    if kind == "all":
        return (Command, RobotState)
    raise KinesphereError("malformed", f"replay {kind!r}? choose one of {', '.join(KINDS)}")


ANSWERS_QUIET_S: Final = 0.5
"""After the last command, a replay waits for the robots' answers until none came for this
long (once one came) ..."""
ANSWERS_MAX_S: Final = 3.0
"""... or this long in all."""
ACTED: Final = frozenset({AckStage.ACCEPTED, AckStage.ESTOPPED, AckStage.RELEASED,
                          AckStage.STOPPED, AckStage.HOLDING, AckStage.LEASED})
"""The first stage a robot gives a command it acts on (one per command and robot)."""
DROPPED: Final = ("stale", "expired")
"""Refusal codes of a command the robot dropped for its age (``--restamp`` sends anew)."""


class Answers:
    """The robots' acks to the commands a replay put, counted per command and robot by what
    became of them: acted on, dropped as ``stale`` or ``expired`` (per robot), or refused
    with another code. An ack counts when its ``(sender, session)`` is one the replay put and
    its ``seq`` lies within what it put there (:data:`MAX_SESSIONS` pairs remembered), so
    other clients' acks do not count. Fed on Zenoh's thread, read after the replay."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._put: Lru[tuple[str, str], list[int]] = Lru(MAX_SESSIONS)
        self.acted = 0
        self.dropped: dict[str, dict[str, int]] = {}
        """Code (:data:`DROPPED`) -> robot -> commands."""
        self.refused: dict[str, int] = {}
        """Code -> commands."""
        self.last_at: float | None = None
        """When the last answer came (monotonic)."""

    def sent(self, cmd: Command) -> None:
        with self._lock:
            span = self._put.get((cmd.sender, cmd.session))
            if span is None:
                self._put.put((cmd.sender, cmd.session), [cmd.seq, cmd.seq])
            else:
                span[0], span[1] = min(span[0], cmd.seq), max(span[1], cmd.seq)

    def on_sample(self, sample: zenoh.Sample) -> None:
        try:
            ack = decode_any(sample.payload)
        except KinesphereError:
            return
        if not isinstance(ack, Ack):
            return
        with self._lock:
            span = self._put.get((ack.sender, ack.session))
            if span is None or not span[0] <= ack.seq <= span[1]:
                return
            self.last_at = time.monotonic()
            if ack.stage in ACTED:
                self.acted += 1
            elif ack.stage != AckStage.REJECTED:
                return
            elif ack.code in DROPPED:
                by = self.dropped.setdefault(ack.code, {})
                by[ack.robot_id] = by.get(ack.robot_id, 0) + 1
            else:
                self.refused[ack.code] = self.refused.get(ack.code, 0) + 1

    def wait(self, should_stop: Callable[[], bool], most: float = ANSWERS_MAX_S) -> None:
        """Give the robots a moment to answer the last commands put: until none came for
        :data:`ANSWERS_QUIET_S` once one came, at most ``most`` seconds, or a stop."""
        start = time.monotonic()
        end = start + most
        while (now := time.monotonic()) < end and not should_stop():
            with self._lock:
                last = self.last_at
            if last is not None and now - max(last, start) >= ANSWERS_QUIET_S:
                return
            time.sleep(0.05)

    def words(self, commands: int, path: str | Path, restamp: bool) -> tuple[str, int]:
        """What became of the ``commands`` put, for people, and the exit status: 0 when
        robots acted on them and dropped or refused none, 1 otherwise (nobody answered, a
        command dropped or refused). Commands dropped for their age name the replay that
        sends them as new (unless it was one)."""
        with self._lock:
            acted, dropped, refused = self.acted, dict(self.dropped), dict(self.refused)
        if not (acted or dropped or refused):
            return (f"no robot answered any of the {commands} command(s): none of the robots "
                    "they address is running, or none heard them", 1)
        said = [f"{acted} acted on"]
        for code, by in sorted(dropped.items()):
            robots = ", ".join(f"{rid} {n}" for rid, n in sorted(by.items()))
            said.append(f"{sum(by.values())} dropped as {code} ({robots})")
        if refused:
            said.append("refused: " + ", ".join(f"{n} {code}" for code, n in
                                                sorted(refused.items())))
        text = f"the robots' answers to {commands} command(s), per robot: " + "; ".join(said)
        if dropped and not restamp:
            text += ("\nthe robots dropped them for their age: they had heard the recorded "
                     "session (stale) or its commands are older than their ttl (expired); "
                     f"send them as new commands with '{hints.replay(str(path), restamp=True)}'")
        return text, 0 if acted and not (dropped or refused) else 1


@dataclass(frozen=True)
class Replayed:
    """What a replay did: how many messages it put (``commands`` of them commands), the
    recorded keys nobody subscribed to when it began (their messages went out to no one), how
    many silences it shortened, what the robots answered to the commands, and whether it was
    stopped before the end."""

    sent: int
    unheard: list[str]
    shortened: int = 0
    commands: int = 0
    answers: Answers = field(default_factory=Answers)
    interrupted: bool = False
    unseen: list[str] = field(default_factory=list)
    """The robots its commands name whose liveliness token it had not seen when it began."""


def replay_key(keys: Keys, topic: str, kind: type[Message]) -> str:
    """``topic`` if it is a key a replay may put ``kind`` on (module text); malformed
    naming it otherwise."""
    rest = topic.split("/")
    n = keys.prefix.count("/") + 1
    ok = "/".join(rest[:n]) == keys.prefix and topic.count("/") < 16
    rest = rest[n:]
    try:
        if ok and kind is Command and len(rest) in (3, 4) and rest[2] == "command":
            base = keys.command(rest[1]) if rest[0] == "robot" else (
                keys.group_command(rest[1]) if rest[0] == "group" else "")
            signer = keys.sender_of(topic) if base else ""
            if base and (Keys.signed(base, signer) if signer else base) == topic:
                return topic
        if ok and kind is RobotState and len(rest) == 3 and rest[0] == "robot" and \
                rest[2] == "state" and keys.state(keys.robot_id_of(topic)) == topic:
            return topic
    except KinesphereError:
        pass
    what = "command" if kind is Command else "state"
    raise KinesphereError(
        "malformed", f"the recording puts {what}s on {topic!r:.120}, which is not a {what} key "
        f"of kinesphere under {keys.prefix!r}: nothing replayed")


@dataclass(frozen=True)
class Survey:
    """What a recording would put, read before anything is: the type of each channel to
    replay (by topic, in order of first appearance) and whether it is a gamepad's."""

    topics: dict[str, type[Message]]
    gamepad: bool


def survey(path: str | Path, keys: Keys, kinds: tuple[type[Message], ...]) -> Survey:
    """The channels of ``kinds`` in the recording, each checked by :func:`replay_key`."""
    schemas: dict[int, str] = {}
    topics: dict[str, type[Message]] = {}
    gamepad = False
    for record in described(path):
        if isinstance(record, McapSchema):
            schemas[record.id] = record.name
        elif isinstance(record, Channel):
            kind = BY_NAME.get(schemas.get(record.schema_id, ""))
            if kind in kinds and record.topic not in topics:
                assert kind is not None
                topics[replay_key(keys, record.topic, kind)] = kind
                if len(topics) > MAX_CHANNELS:
                    raise KinesphereError("malformed", f"{path}: more than {MAX_CHANNELS} keys")
        elif isinstance(record, Metadata) and record.name == "kinesphere":
            gamepad = record.metadata.get("kinesphere") == GAMEPAD_RECORDING
    return Survey(topics, gamepad)


def replay(session: zenoh.Session, path: str | Path, kind: str = "commands",
           speed: float = 1.0, should_stop: Callable[[], bool] = lambda: False,
           on_put: Callable[[str, Message], None] | None = None, restamp: bool = False,
           wait: float = WAIT_S, *, keys: Keys | None = None, sender: str | None = None,
           max_gap: float = MAX_GAP_S, answers_for: float = ANSWERS_MAX_S) -> Replayed:
    """Put the recording's ``kind`` messages back on their keys with the original timing
    (commands as ``sender``'s new ones with ``restamp``), once each key has a subscriber and
    (unless ``answers_for`` is 0) each robot a command key names is seen alive, or ``wait``
    seconds have passed; unavailable when no key has a subscriber by then. The robots'
    answers to the commands put are counted for at most ``answers_for`` seconds after the
    last one (0: the caller does not count them, and puts to subscribers that are no
    robots)."""
    if not speed > 0:
        raise KinesphereError("malformed", f"--speed must be > 0, got {speed}")
    if not wait >= 0:
        raise KinesphereError("malformed", f"--wait must be >= 0, got {wait}")
    if not max_gap >= 0:
        raise KinesphereError("malformed", f"--max-gap must be >= 0, got {max_gap}")
    keys = keys or Keys()
    kinds = wanted(kind)
    found = survey(path, keys, kinds)
    if not found.topics:
        if found.gamepad:
            raise KinesphereError(
                "malformed", f"{path} holds a gamepad's controller ticks, not messages: play "
                f"it with '{hints.replay_ticks(str(path))}'")
        return Replayed(0, [])
    me = sender or operator_id()
    sessions: Lru[tuple[str, str], str] = Lru(MAX_SESSIONS)
    clock = host_clock()

    put_on = {topic: topic for topic in found.topics}
    if restamp:  # the replaying operator's commands: keys signed with its name
        put_on.update({topic: Keys.signed(topic.rsplit("/", 1)[0] if keys.sender_of(topic)
                                          else topic, me)
                       for topic, type_ in found.topics.items() if type_ is Command})
    publishers: dict[str, Any] = {}
    sent = shortened = commands = 0
    answers = Answers()
    listener = None
    try:
        if Command in found.topics.values():
            listener = session.declare_subscriber(keys.ack(WILDCARD), answers.on_sample)
        deadline = time.monotonic() + wait
        for key in dict.fromkeys(put_on.values()):
            publishers[key] = _publisher(session, key)
        unheard = unmatched(publishers, wait)
        if len(unheard) == len(publishers):
            raise KinesphereError("unavailable", f"nobody listens on {few(unheard)} (waited "
                                  f"{wait:g} s): nothing replayed")
        robots = _robots_named(keys, found.topics) if answers_for > 0 else []
        missing = unseen(session, keys.alive_robot(WILDCARD), [keys.alive_robot(r) for r in robots],
                         max(0.0, deadline - time.monotonic()))
        not_alive = [keys.robot_id_of(token) for token in missing]
        due, last_ns = time.monotonic(), None
        for raw in messages(path):
            kind_of = found.topics.get(raw.topic)
            if kind_of is None or BY_NAME.get(raw.schema) is not kind_of:
                continue  # not replayed (acks, poses), or not the type its channel said
            msg = decode_recorded(raw, path)
            gap = 0.0 if last_ns is None else max(0.0, (raw.log_ns - last_ns) / 1e9)
            last_ns = raw.log_ns
            if gap > max_gap:
                gap, shortened = max_gap, shortened + 1
            due += gap / speed
            while (left := due - time.monotonic()) > 0:
                if should_stop():
                    return Replayed(sent, unheard, shortened, commands, answers, True,
                                    not_alive)
                time.sleep(min(left, 0.05))
            if restamp and isinstance(msg, Command):
                msg = _restamped(msg, me, clock, sessions)
            if isinstance(msg, Command):
                answers.sent(msg)
                commands += 1
            key = put_on[raw.topic]
            try:
                publishers[key].put(encode(msg))
            except zenoh.ZError as exc:
                raise KinesphereError("unavailable", f"put on {key!r:.120}: {exc}") from None
            sent += 1
            if on_put is not None:
                on_put(key, msg)
        if commands:
            answers.wait(should_stop, answers_for)
    finally:
        undeclare(*publishers.values(), listener)
    return Replayed(sent, unheard, shortened, commands, answers, should_stop(), not_alive)


def _robots_named(keys: Keys, topics: dict[str, type[Message]]) -> list[str]:
    """The robots named by the command keys among ``topics`` (not ``*``, not groups)."""
    robots: dict[str, None] = {}
    for topic, kind in topics.items():
        if kind is Command:
            try:
                robots[keys.robot_id_of(topic)] = None
            except KinesphereError:
                continue  # every robot's key, or a group's
    return list(robots)


def _publisher(session: zenoh.Session, key: str) -> Any:
    try:
        return session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK,
                                         express=True)
    except zenoh.ZError as exc:  # the keys are checked first: this is a session closing
        raise KinesphereError("malformed", f"cannot put on {key!r:.120}: {exc}") from None


def few(keys: list[str], most: int = 3) -> str:
    """``keys`` for a message: the first ``most`` and how many more."""
    more = f" and {len(keys) - most} more" if len(keys) > most else ""
    return ", ".join(keys[:most]) + more


def _restamped(cmd: Command, sender: str, clock: str,
               sessions: Lru[tuple[str, str], str]) -> Command:
    """``cmd`` sent now by ``sender``, in a fresh session standing for its recorded one (the
    :data:`MAX_SESSIONS` most recent are remembered)."""
    key = (cmd.sender, cmd.session)
    session = sessions.get(key) or sessions.put(key, new_session())
    return msgspec.structs.replace(cmd, sent_ns=time.time_ns(), sender=sender, session=session,
                                   clock=clock)


def summary(tally: Tally, path: Path) -> str:
    kinds = ", ".join(f"{n} {t}" for t, n in sorted(tally.by_type.items()))
    bad = f"; {tally.undecodable} undecodable skipped" if tally.undecodable else ""
    return f"recorded {tally.recorded} messages to {path} ({kinds or 'none'}){bad}"


