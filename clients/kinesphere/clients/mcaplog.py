"""Sessions in MCAP: kinesphere messages with JSON schemas, readable by Foxglove and ``mcap``.

One channel per Zenoh key (``kinesphere/robot/baxter-1/state``), one schema per message type
(``kinesphere.RobotState``: the JSON Schema msgspec derives from :mod:`kinesphere.protocol`),
messages encoded as JSON. JSON rather than the wire's MessagePack because Foxglove and the
``mcap`` CLI decode JSON with a JSON Schema out of the box; msgspec writes floats so that they
read back exactly, so a message survives the round trip unchanged. ``log_time`` is when the
recorder received the message, ``publish_time`` the sender's own stamp when it has one.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Final

import msgspec
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from kinesphere.errors import KinesphereError
from kinesphere.protocol import MESSAGE_TYPES, PROTOCOL_VERSION, AnyMessage, Message

SCHEMA_PREFIX: Final = "kinesphere."
GAMEPAD_RECORDING: Final = "gamepad-recording"
"""The ``kinesphere`` metadata value of a gamepad's controller ticks (``gamepad --record``):
the gamepad replays such a file, ``kinesphere replay`` names it and refuses it."""
LIBRARY: Final = f"kinesphere (protocol {PROTOCOL_VERSION})"
BY_NAME: Final[dict[str, type[Message]]] = {
    f"{SCHEMA_PREFIX}{t.__name__}": t for t in MESSAGE_TYPES
}


@dataclass(frozen=True)
class Recorded:
    """One message of a recording: its key, the message, and when (ns since the epoch)."""

    key: str
    message: AnyMessage
    log_ns: int
    publish_ns: int


def stamp_of(msg: Message) -> int | None:
    """The sender's own time of a message, when it carries one."""
    for field in ("stamp_ns", "sent_ns"):
        value = getattr(msg, field, None)
        if isinstance(value, int):
            return value
    return None


class McapWriter:
    """Writes messages to an MCAP file; :meth:`close` finishes it (summary, index, CRCs)."""

    def __init__(self, path: str | Path, metadata: dict[str, str] | None = None) -> None:
        self.path = Path(path)
        try:
            self._f: IO[bytes] = self.path.open("wb")
        except OSError as exc:
            raise KinesphereError("malformed", f"cannot write {path}: {exc.strerror}") from None
        self._w = Writer(self._f, compression=CompressionType.ZSTD)
        self._w.start(profile="", library=LIBRARY)
        if metadata:
            self._w.add_metadata("kinesphere", metadata)
        self._schemas: dict[type[Any], int] = {}
        self._channels: dict[str, int] = {}
        self._seq = 0
        self.count = 0
        self.bytes = 0

    def _channel(self, key: str, type_: type[Any]) -> int:
        channel = self._channels.get(key)
        if channel is None:
            schema = self._schemas.get(type_)
            if schema is None:
                data = json.dumps(msgspec.json.schema(type_)).encode()
                schema = self._schemas[type_] = self._w.register_schema(
                    name=f"{SCHEMA_PREFIX}{type_.__name__}", encoding="jsonschema", data=data)
            channel = self._channels[key] = self._w.register_channel(
                topic=key, message_encoding="json", schema_id=schema)
        return channel

    def write(self, key: str, msg: Message, log_ns: int, publish_ns: int | None = None) -> None:
        publish = publish_ns if publish_ns is not None else (stamp_of(msg) or log_ns)
        self.write_json(key, type(msg), msgspec.json.encode(msg), log_ns, publish)

    def write_json(self, key: str, type_: type[Any], data: bytes, log_ns: int,
                   publish_ns: int | None = None) -> None:
        """One JSON message of ``type_`` (any type msgspec derives a schema for)."""
        self._w.add_message(self._channel(key, type_), log_time=log_ns, data=data,
                            publish_time=log_ns if publish_ns is None else publish_ns,
                            sequence=self._seq)
        self._seq += 1
        self.count += 1
        self.bytes += len(data)

    def close(self) -> None:
        self._w.finish()  # type: ignore[no-untyped-call]
        self._f.close()

    def __enter__(self) -> McapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class Raw:
    """One message of a recording as stored: schema name, topic, JSON bytes, times."""

    schema: str
    topic: str
    data: bytes
    log_ns: int
    publish_ns: int


def messages(path: str | Path, schema: str | None = None) -> Iterator[Raw]:
    """Every message of a recording (of one schema, if given) in log-time order, undecoded."""
    try:
        f = Path(path).open("rb")
    except OSError as exc:
        raise KinesphereError("malformed", f"cannot read {path}: {exc.strerror}") from None
    with f:
        try:
            for sch, channel, message in make_reader(f).iter_messages(log_time_order=True):
                if sch is not None and (schema is None or sch.name == schema):
                    yield Raw(sch.name, channel.topic, message.data, message.log_time,
                              message.publish_time)
        except KinesphereError:
            raise
        except Exception as exc:  # the mcap library raises assorted types on a broken file
            raise KinesphereError("malformed", f"{path} is not a readable MCAP file: {exc}"
                                  ) from None


def read(path: str | Path) -> Iterator[Recorded]:
    """Every kinesphere message of a recording in log-time order, decoded and checked."""
    for raw in messages(path):
        if raw.schema not in BY_NAME:
            continue  # another tool's channel (or the gamepad's input): not ours to replay
        try:
            msg = msgspec.json.decode(raw.data, type=BY_NAME[raw.schema])
        except msgspec.DecodeError as exc:  # bad JSON, or a field the schema does not allow
            raise KinesphereError(
                "malformed", f"{path}: bad {raw.schema} on {raw.topic}: {exc}"
            ) from None
        yield Recorded(raw.topic, msg, raw.log_ns, raw.publish_ns)  # type: ignore[arg-type]


def metadata(path: str | Path) -> dict[str, str]:
    """The ``kinesphere`` metadata record of a recording (empty when it has none)."""
    try:
        with Path(path).open("rb") as f:
            for record in make_reader(f).iter_metadata():
                if record.name == "kinesphere":
                    return dict(record.metadata)
    except OSError as exc:
        raise KinesphereError("malformed", f"cannot read {path}: {exc.strerror}") from None
    except Exception as exc:
        raise KinesphereError("malformed", f"{path} is not a readable MCAP file: {exc}") from None
    return {}
