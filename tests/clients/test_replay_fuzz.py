"""``kinesphere replay`` of recordings someone hands over: streamed, bounded, keys checked.

Before: a 33 KB zstd bomb peaked at 2.16 GB; a million messages loaded whole (1.05 GB, 18 s
before the first put); keys such as ``a//b``, ``$*``, ``#`` ended in a ``zenoh.ZError``
traceback while ``**`` and ``kinesphere/ecl/youbot/record`` were put on; a 2^63 gap in log
time waited forever. Real Zenoh sessions on loopback, files written by the recorder's own
writer or assembled record by record with the mcap library. ``make soak`` runs the stream
and the fuzz ``KINESPHERE_SOAK_SCALE`` times larger and prints one ``SOAK`` line each.
"""

from __future__ import annotations

import os
import random
import time
from pathlib import Path

import pytest
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, DataEnd, Footer, Header, Schema

from kinesphere import protocol as pr
from kinesphere import zconfig
from kinesphere.clients import mcaplog
from kinesphere.clients.mcaplog import McapWriter, messages
from kinesphere.clients.recording.traffic import replay
from kinesphere.errors import KinesphereError
from kinesphere.keyexpr import Keys
from support.network import NO_ROBOTS
from support.network import OWN_KEYS as KEYS
from support.soak import MIB, SCALE, FloodTally, mib, rss
from support.wait import WAIT_S, until

MESSAGES = 20_000 * SCALE
MUTANTS = 300 * SCALE
MAGIC = b"\x89MCAP0\r\n"


def _rss() -> int:
    return rss(os.getpid())


def _command(i: int) -> pr.Command:
    return pr.Command(seq=i, sent_ns=1_700_000_000_000_000_000 + i, deadman=False, ttl_ms=0,
                      stop=True, sender="rec", session="s")


def _recording(path: Path, n: int, topic: str | None = None, gap_ns: int = 1000) -> Path:
    with McapWriter(path, {"prefix": KEYS.prefix}) as w:
        for i in range(n):
            w.write(topic or KEYS.command(f"r{i % 4}"), _command(i), 1_000_000 + i * gap_ns)
    return path


def _bomb(path: Path, inflated: int) -> Path:
    """A recording whose one chunk is ``inflated`` bytes of zeros, compressed (a few dozen KB
    for hundreds of MB) in a frame that declares its size, in a chunk that says it is small
    (a reader that trusts the frame allocates it all at once)."""
    cctx = zstandard.ZstdCompressor(level=19).compressobj(size=inflated)
    block = bytes(1 << 20)
    data = b"".join(cctx.compress(block) for _ in range(inflated >> 20)) + cctx.flush()
    out = RecordBuilder()
    Header(profile="", library="bomb").write(out)
    schema = Schema(id=1, name="kinesphere.Command", encoding="jsonschema", data=b"{}")
    schema.write(out)
    Channel(id=1, schema_id=1, topic=KEYS.command("r1"), message_encoding="json",
            metadata={}).write(out)
    Chunk(message_start_time=0, message_end_time=0, uncompressed_size=1024,
          uncompressed_crc=0, compression="zstd", data=data).write(out)
    DataEnd(data_section_crc=0).write(out)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(out)
    # mcap's RecordBuilder.end() has no annotations (it returns the bytes built)
    path.write_bytes(MAGIC + out.end() + MAGIC)  # type: ignore[no-untyped-call]
    return path


def test_a_zstd_bomb_is_refused_without_inflating_it(tmp_path: Path) -> None:
    bomb = _bomb(tmp_path / "bomb.mcap", 512 * MIB)
    before = _rss()
    with pytest.raises(KinesphereError) as err:
        list(messages(bomb))
    grew = _rss() - before
    assert err.value.code == "malformed" and "inflates past" in err.value.message
    assert grew < 48 * MIB, f"reading a {bomb.stat().st_size}-byte bomb took {mib(grew)}"
    with zconfig.loopback_hub() as (hub, _):
        with pytest.raises(KinesphereError) as err:
            replay(hub, bomb, keys=KEYS, wait=0.1)
        assert err.value.code == "malformed"


@pytest.mark.parametrize("topic", [f"{KEYS.prefix}/{rest}" for rest in (
    "a//b", "robot/$*/command", "robot/#/command", "robot/r?/command", "**",
    "ecl/youbot/record", "robot/r1/state", "robot/r1/command/a/b", "group/*/command",
    "robot/@r1/command")] + ["**", "kinesphere/robot/r1/command"])
def test_only_the_projects_command_keys_are_replayed(tmp_path: Path, topic: str) -> None:
    path = _recording(tmp_path / "keys.mcap", 3, topic)
    with zconfig.loopback_hub() as (hub, endpoint), \
            zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        heard: list[str] = []
        sub = s.declare_subscriber("**", lambda sample: heard.append(str(sample.key_expr)))
        with pytest.raises(KinesphereError) as err:
            replay(hub, path, keys=KEYS, wait=0.2)
        zconfig.undeclare(sub)
    assert err.value.code == "malformed" and "nothing replayed" in err.value.message
    assert heard == []


def test_the_projects_own_keys_are_replayed(tmp_path: Path) -> None:
    good = [KEYS.command("r1"), KEYS.command("*"), KEYS.group_command("arms"),
            Keys.signed(KEYS.command("*"), "alice"), Keys.signed(KEYS.group_command("g"), "b")]
    with zconfig.loopback_hub() as (hub, endpoint), \
            zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        heard: list[str] = []
        sub = s.declare_subscriber(f"{KEYS.prefix}/**",
                                   lambda sample: heard.append(str(sample.key_expr)))
        for i, topic in enumerate(good):
            done = replay(hub, _recording(tmp_path / f"{i}.mcap", 1, topic), keys=KEYS,
                          wait=20.0, answers_for=NO_ROBOTS)
            assert done.sent == 1 and done.unheard == []
        until(lambda: len(heard) >= len(good), WAIT_S, "every replayed key heard",
              explain=lambda: heard)
        zconfig.undeclare(sub)
    assert sorted(heard) == sorted(good)


def test_a_long_silence_in_the_recording_is_shortened(tmp_path: Path) -> None:
    path = _recording(tmp_path / "gap.mcap", 3, KEYS.command("r1"), gap_ns=2**62)
    with zconfig.loopback_hub() as (hub, endpoint), \
            zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        sub = s.declare_subscriber(Keys.subscribed(KEYS.command("r1")), lambda sample: None)
        t0 = time.monotonic()
        done = replay(hub, path, keys=KEYS, wait=20.0, max_gap=0.05, answers_for=NO_ROBOTS)
        took = time.monotonic() - t0
        zconfig.undeclare(sub)
    assert done.sent == 3 and done.shortened == 2 and took < 30.0


def test_a_long_recording_streams_in_bounded_memory(tmp_path: Path) -> None:
    """The reader holds one chunk at a time: the first message comes out after one chunk
    is opened, and replaying them all moves the process's memory by a bounded amount."""
    path = _recording(tmp_path / "long.mcap", MESSAGES)
    opened = []
    original = mcaplog._inflate

    def counting(chunk: Chunk, where: str | Path) -> bytes:
        opened.append(len(chunk.data))
        return original(chunk, where)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(mcaplog, "_inflate", counting)
        first = next(messages(path))
    assert first.topic == KEYS.command("r0") and len(opened) == 1
    got = [0]
    with zconfig.loopback_hub() as (hub, endpoint), \
            zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        sub = s.declare_subscriber(Keys.subscribed(KEYS.command("*")),
                                   lambda sample: got.__setitem__(0, got[0] + 1))
        before = _rss()
        first_put: list[float] = []
        t0 = time.monotonic()
        done = replay(hub, path, keys=KEYS, wait=20.0, speed=1e9, answers_for=NO_ROBOTS,
                      on_put=lambda k, m: (
            first_put.append(time.monotonic() - t0) if not first_put else None))
        grew = _rss() - before
        until(lambda: got[0] >= MESSAGES, WAIT_S, f"{MESSAGES} messages delivered",
              explain=lambda: got[0])
        zconfig.undeclare(sub)
    tally = FloodTally("replay stream")
    tally.sent = done.sent
    tally.extra.update({"delivered": got[0], "file": mib(path.stat().st_size),
                        "RSS growth": mib(grew),
                        "first put after": f"{first_put[0]:.2f} s",
                        "all put in": f"{time.monotonic() - t0:.1f} s"})
    tally.report()
    assert done.sent == MESSAGES and got[0] == MESSAGES
    assert grew < 64 * MIB, f"replaying {MESSAGES} messages grew the process by {mib(grew)}"


def _mutate(data: bytes, rng: random.Random) -> bytes:
    out = bytearray(data)
    kind = rng.randrange(4)
    if kind == 0:  # flip bytes
        for _ in range(rng.randint(1, 8)):
            out[rng.randrange(len(out))] = rng.randrange(256)
    elif kind == 1:  # cut
        out = out[: rng.randrange(len(out))]
    elif kind == 2:  # splice a block elsewhere
        a, b = sorted(rng.randrange(len(out)) for _ in range(2))
        at = rng.randrange(len(out))
        out[at:at] = out[a:b]
    else:  # a length field made huge
        at = rng.randrange(max(1, len(out) - 8))
        out[at:at + 8] = rng.choice([b"\xff" * 8, (2**40).to_bytes(8, "little")])
    return bytes(out)


def test_mutated_recordings_are_refused_by_name(tmp_path: Path) -> None:
    source = _recording(tmp_path / "src.mcap", 40).read_bytes()
    rng = random.Random(29)
    tally = FloodTally("replay fuzz")
    path = tmp_path / "mutant.mcap"
    before = _rss()
    with zconfig.loopback_hub() as (hub, endpoint), \
            zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        sub = s.declare_subscriber(Keys.subscribed(KEYS.command("*")), lambda sample: None)
        for _ in range(MUTANTS):
            path.write_bytes(_mutate(source, rng))
            tally.sent += 1
            try:
                done = replay(hub, path, keys=KEYS, wait=5.0, speed=1e9, max_gap=0.01,
                              answers_for=NO_ROBOTS)
                tally.add(f"replayed {'all' if done.sent == 40 else 'some'}")
            except KinesphereError as exc:
                tally.add(exc.code)
        zconfig.undeclare(sub)
    tally.extra["RSS growth"] = mib(_rss() - before)
    tally.report()
    assert set(tally.codes) <= {"malformed", "replayed all", "replayed some"}, tally.codes
    assert tally.codes["malformed"] > 0


def test_a_recording_that_is_no_mcap_at_all(tmp_path: Path) -> None:
    for data in (b"", MAGIC, MAGIC + bytes([Opcode.CHUNK]) + b"\xff" * 8, b"x" * 100):
        path = tmp_path / "x.mcap"
        path.write_bytes(data)
        with pytest.raises(KinesphereError) as err, zconfig.loopback_hub() as (hub, _):
            replay(hub, path, keys=KEYS, wait=0.1)
        assert err.value.code == "malformed", data
