"""Sessions in MCAP: kinesphere messages with JSON schemas, readable by Foxglove and ``mcap``.

One channel per Zenoh key (``kinesphere/robot/baxter-1/state``), one schema per message type
(``kinesphere.RobotState``: the JSON Schema msgspec derives from :mod:`kinesphere.protocol`),
messages encoded as JSON. JSON rather than the wire's MessagePack because Foxglove and the
``mcap`` CLI decode JSON with a JSON Schema out of the box; msgspec writes floats so that they
read back exactly, so a message survives the round trip unchanged. ``log_time`` is when the
recorder received the message, ``publish_time`` the sender's own stamp when it has one.

Reading streams the file record by record, in file order (which is arrival order for the
files the recorder writes), holding one chunk at a time: a recording is any file someone
hands over, so every size is bounded before it is allocated. A chunk's compressed record at
most :data:`MAX_RECORD_BYTES`, inflated at most :data:`MAX_CHUNK_BYTES` (read through a
bounded decompressing stream: a compressed frame may declare any size it likes, and the mcap
library would allocate it) and at most :data:`MAX_RATIO` times its compressed size, a message
at most :data:`MAX_MESSAGE_BYTES`, at most :data:`MAX_CHANNELS` channels. Past a bound the
file is ``malformed``, named.
"""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any, Final

import msgspec
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, McapRecord, Metadata, MetadataIndex, Schema
from mcap.records import Message as McapMessage
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from kinesphere.closing import Closable
from kinesphere.errors import KinesphereError
from kinesphere.protocol import MESSAGE_TYPES, PROTOCOL_VERSION, AnyMessage, Message

SCHEMA_PREFIX: Final = "kinesphere."
GAMEPAD_RECORDING: Final = "gamepad-recording"
"""The ``kinesphere`` metadata value of a gamepad's controller ticks (``gamepad --record``):
the gamepad replays such a file, ``kinesphere replay`` names it and refuses it."""
MAX_RECORD_BYTES: Final = 64 * 1024 * 1024
"""Bytes of one record as the file holds it (a chunk: compressed)."""
MAX_CHUNK_BYTES: Final = 16 * 1024 * 1024
"""Bytes of one chunk inflated (the writer's chunks are 1 MiB)."""
MAX_RATIO: Final = 1000
"""How many times its compressed size a chunk may inflate to (past 1 MiB; JSON messages
compress 5-50 times): the work a file can cause stays proportional to its size."""
MAX_MESSAGE_BYTES: Final = 4 * 1024 * 1024
"""Bytes of one message's JSON (a wire message is at most 1 MiB of MessagePack)."""
MAX_CHANNELS: Final = 4096
"""Channels (and schemas) of one recording."""
MAGIC: Final = b"\x89MCAP0\r\n"
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


class McapWriter(Closable):
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


@dataclass(frozen=True)
class Raw:
    """One message of a recording as stored: schema name, topic, JSON bytes, times."""

    schema: str
    topic: str
    data: bytes
    log_ns: int
    publish_ns: int


def records(path: str | Path, inflate: bool = True) -> Iterator[McapRecord]:
    """Every record of a recording in file order, chunks opened (``inflate``) or not;
    bounded (module text), malformed naming the file otherwise."""
    try:
        f = Path(path).open("rb")
    except OSError as exc:
        raise KinesphereError("malformed", f"cannot read {path}: {exc.strerror}") from None
    with f:
        try:
            reader = StreamReader(f, emit_chunks=True, record_size_limit=MAX_RECORD_BYTES)
            for record in reader.records:
                if isinstance(record, Chunk) and inflate:
                    yield from _chunk_records(record, path)
                else:
                    yield record
        except KinesphereError:
            raise
        except Exception as exc:  # the mcap library and the codecs raise assorted types
            raise KinesphereError("malformed", f"{path} is not a readable MCAP file: "
                                  f"{type(exc).__name__}: {exc}"[:300]) from None


def described(path: str | Path) -> Iterator[McapRecord]:
    """The schema, channel and metadata records of a recording: read from its summary when it
    has one (the recorder always writes it: a seek and a few records, however long the file),
    else from a pass over the whole file (a recording cut short). A summary that leaves a
    channel out only makes its messages unknown to a reader that trusts it."""
    try:
        summary = _summary(Path(path))
    except Exception:  # a broken summary: the full pass reads the file and names its fault
        summary = None
    if summary is None:
        yield from (r for r in records(path) if isinstance(r, (Schema, Channel, Metadata)))
    else:
        yield from summary


def _summary(path: Path) -> list[McapRecord] | None:
    """The records :func:`described` wants from the summary section; None without one."""
    size = path.stat().st_size
    with path.open("rb") as f:
        if size < 2 * len(MAGIC) + 29:
            return None
        f.seek(size - len(MAGIC) - 29)
        tail = f.read(29 + len(MAGIC))
        if tail[-len(MAGIC):] != MAGIC or tail[0] != Opcode.FOOTER or \
                int.from_bytes(tail[1:9], "little") != 20:
            return None
        start = int.from_bytes(tail[9:17], "little")
        if not 0 < start < size - len(MAGIC) - 29:
            return None
        f.seek(start)
        out: list[McapRecord] = []
        wanted: list[int] = []
        reader = StreamReader(f, skip_magic=True, emit_chunks=True,
                              record_size_limit=MAX_RECORD_BYTES)
        for n, record in enumerate(reader.records):
            if n > 4 * MAX_CHANNELS + 100_000:
                return None  # no summary of ours is that long: read the file instead
            if isinstance(record, (Schema, Channel)):
                out.append(record)
            elif isinstance(record, MetadataIndex) and record.name == "kinesphere":
                wanted.append(record.offset)
        for offset in wanted[:1]:
            f.seek(offset)
            for record in StreamReader(f, skip_magic=True, emit_chunks=True,
                                       record_size_limit=MAX_RECORD_BYTES).records:
                if isinstance(record, Metadata):
                    out.append(record)
                break
        return out


def _inflate(chunk: Chunk, path: str | Path) -> bytes:
    """A chunk's records, decompressed through a stream that stops past the bound."""
    most = min(MAX_CHUNK_BYTES, max(1 << 20, MAX_RATIO * len(chunk.data)))
    if chunk.uncompressed_size > most:
        raise KinesphereError("malformed", f"{path}: a chunk of {len(chunk.data)} bytes says it "
                              f"holds {chunk.uncompressed_size} (at most {most})")
    if chunk.compression == "":
        return bytes(chunk.data)
    if chunk.compression == "zstd":
        import zstandard

        stream: Any = zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data))
        data = stream.read(most + 1)
    elif chunk.compression == "lz4":
        import lz4.frame

        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=most + 1)
    else:
        raise KinesphereError("malformed", f"{path}: chunk compression "
                              f"{chunk.compression!r:.40} (zstd, lz4 or none)")
    if len(data) > most:
        raise KinesphereError("malformed", f"{path}: a chunk of {len(chunk.data)} bytes "
                              f"inflates past {most} bytes")
    return bytes(data)


def _chunk_records(chunk: Chunk, path: str | Path) -> Iterator[McapRecord]:
    """The channel, schema and message records of one chunk, one at a time."""
    data = _inflate(chunk, path)
    stream = ReadDataStream(io.BytesIO(data))
    while stream.count < len(data):
        opcode = stream.read1()
        length = stream.read8()
        if length > len(data) - stream.count:
            raise KinesphereError("malformed", f"{path}: a record runs past its chunk")
        start = stream.count
        if opcode == Opcode.CHANNEL:
            yield Channel.read(stream)
        elif opcode == Opcode.SCHEMA:
            yield Schema.read(stream)
        elif opcode == Opcode.MESSAGE:
            yield McapMessage.read(stream, length)
        padding = length - (stream.count - start)
        if padding < 0:
            raise KinesphereError("malformed", f"{path}: a record overruns its length")
        if padding:
            stream.read(padding)


def messages(path: str | Path, schema: str | None = None) -> Iterator[Raw]:
    """Every message of a recording (of one schema, if given) in file order, undecoded."""
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[int, str]] = {}
    for record in records(path):
        if isinstance(record, Schema):
            _bounded(schemas, path)[record.id] = record.name
        elif isinstance(record, Channel):
            _bounded(channels, path)[record.id] = (record.schema_id, record.topic)
        elif isinstance(record, McapMessage):
            if len(record.data) > MAX_MESSAGE_BYTES:
                raise KinesphereError("malformed", f"{path}: a message of {len(record.data)} "
                                      f"bytes (at most {MAX_MESSAGE_BYTES})")
            found = channels.get(record.channel_id)
            name = schemas.get(found[0]) if found is not None else None
            if found is not None and name is not None and (schema is None or name == schema):
                yield Raw(name, found[1], record.data, record.log_time, record.publish_time)


def _bounded(table: dict[int, Any], path: str | Path) -> dict[int, Any]:
    if len(table) >= MAX_CHANNELS:
        raise KinesphereError("malformed", f"{path}: more than {MAX_CHANNELS} channels or "
                              "schemas")
    return table


def read(path: str | Path) -> Iterator[Recorded]:
    """Every kinesphere message of a recording in file order, decoded and checked."""
    for raw in messages(path):
        if raw.schema not in BY_NAME:
            continue  # another tool's channel (or the gamepad's input): not ours to replay
        msg = decode_recorded(raw, path)
        yield Recorded(raw.topic, msg, raw.log_ns, raw.publish_ns)  # type: ignore[arg-type]


def decode_recorded(raw: Raw, path: str | Path) -> Message:
    """A recorded kinesphere message, checked as its schema says (the wire's bounds)."""
    try:
        msg: Message = msgspec.json.decode(raw.data, type=BY_NAME[raw.schema])
    except (msgspec.DecodeError, RecursionError) as exc:  # bad JSON, or a field out of bounds
        raise KinesphereError(
            "malformed", f"{path}: bad {raw.schema} on {raw.topic!r:.120}: {exc}"[:400]
        ) from None
    return msg


def metadata(path: str | Path) -> dict[str, str]:
    """The ``kinesphere`` metadata record of a recording (empty when it has none)."""
    for record in records(path, inflate=False):  # metadata never sits inside a chunk
        if isinstance(record, Metadata) and record.name == "kinesphere":
            return dict(record.metadata)
    return {}
