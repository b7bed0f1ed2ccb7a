"""Databank pose queries over loopback against the floor: a bare Zenoh echo queryable.

A server process hosts both the databank service and the floor, a Python callback that
replies a pre-encoded payload of exactly the service's reply size (the least any Python
queryable can do). This process queries both over loopback TCP, interleaved query by query, so
machine noise hits both alike; the ratio service / floor is what the databank itself costs.
Server and client are separate processes, as in deployment (one process would make them
contend for one GIL). Targets: p50 <= 1.2x the floor.
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import zenoh

from kinesphere.keyexpr import Keys
from kinesphere.platforms.platform import load_platform
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.store import PoseRow, default_db_path, write_databank
from kinesphere.services.ecl.vsam import load_vsam
from kinesphere.zconfig import close_session, loopback_endpoint, session_config, undeclare

KEYS = Keys("kbench")
"""The service as ``serve`` runs it by default: it serves every known platform."""
SUBSET_KEYS = Keys("ksubst")
"""A replica serving some known platforms only: one more (catch-all) queryable."""
FLOOR_PREFIX = "kfloor"  # as long as the service prefixes, so keys weigh the same
QUERIES = 6000
WARMUP = 300
THREADS = 4
THROUGHPUT_SECONDS = 0.5
THROUGHPUT_ROUNDS = 8
ROOT = Path(__file__).resolve().parents[1]
TOYARM = ROOT / "tests" / "data" / "toyarm"


def _databank(tmp: Path) -> tuple[str, str, tuple[str, str, str, float]]:
    """(platform, db path, a stored cell): Baxter's shipped databank, else a toyarm one."""
    if default_db_path("baxter").is_file():
        ecl = Ecl.open("baxter")
        cell = ecl.cells()[len(ecl.cells()) // 2]
        cmd = (cell.limb, cell.origin, cell.direction.slug, float(cell.sizes[-1]))
        return "baxter", str(ecl.db_path), cmd
    plat = load_platform(str(TOYARM))
    rows = [
        PoseRow("limb_11", "distal_11", "left-high", s, {"yaw": s / 10, "elbow": 0.2, "wrist": 0.1})
        for s in (1, 2, 3)
    ]
    path = tmp / "toyarm.sqlite"
    write_databank(path, plat, load_vsam(plat), rows, "bench")
    return str(TOYARM), str(path), ("limb_11", "distal_11", "left-high", 2.0)


def serve(endpoint: str, platform: str, db: str, reply_size: int, mode: str = "peer") -> None:
    """The server process: databank + floor on one session until stdin closes; a peer
    listening on ``endpoint``, or (``mode="client"``) a client of the router there."""
    from kinesphere.services.databank.service import DatabankService
    from kinesphere.zconfig import open_session

    ecl = Ecl.open(platform, db)
    if mode == "client":
        session = open_session(session_config("client", listen=[], connect=[endpoint]))
    else:
        session = open_session(session_config("peer", listen=[endpoint], connect=[]))
    payload = zenoh.ZBytes(b"\x00" * reply_size)

    def echo(query: zenoh.Query) -> None:
        with query:
            query.reply(query.key_expr, payload)

    ecls = {ecl.platform.name: ecl}
    try:
        with (
            DatabankService(session, ecls, KEYS, "bench", known_platforms=()),
            DatabankService(session, ecls, SUBSET_KEYS, "subset", known_platforms=["baxter"]),
        ):
            floor = session.declare_queryable(f"{FLOOR_PREFIX}/**", echo, complete=True)
            print("ready", flush=True)
            sys.stdin.read()
            undeclare(floor)
    finally:
        close_session(session)


def _first_reply(session: zenoh.Session, key: str) -> bytes | None:
    for reply in session.get(key, consolidation=zenoh.ConsolidationMode.NONE, timeout=5.0):
        if reply.err is not None:
            raise RuntimeError(f"{key}: error reply {reply.err.payload.to_bytes()!r}")
        if reply.ok is not None:
            return reply.ok.payload.to_bytes()
    return None


def _wait_reply(session: zenoh.Session, key: str, timeout: float = 10.0) -> bytes:
    deadline = time.monotonic() + timeout
    while (reply := _first_reply(session, key)) is None:
        if time.monotonic() > deadline:
            raise RuntimeError(f"{key}: no reply within {timeout} s")
    return reply


def _latencies(session: zenoh.Session, keys: Sequence[str], n: int) -> list[list[float]]:
    """Microseconds from ``get`` to the first reply, per key: ``n`` rounds in which each key
    is asked once (order reversed every other round), so every key sees the same noise."""
    get, none = session.get, zenoh.ConsolidationMode.NONE
    clock = time.perf_counter_ns
    out: list[list[float]] = [[] for _ in keys]
    order = list(enumerate(keys))
    for i in range(n):
        for j, key in order if i % 2 else order[::-1]:
            t0 = clock()
            for _reply in get(key, consolidation=none, timeout=5.0):
                break
            out[j].append((clock() - t0) / 1000.0)
    return out


def _throughput(session: zenoh.Session, key: str) -> float:
    """Queries per second answered to THREADS threads querying back to back."""
    counts = [0] * THREADS
    stop = threading.Event()
    go = threading.Barrier(THREADS + 1)

    def querier(i: int) -> None:
        get, none = session.get, zenoh.ConsolidationMode.NONE
        go.wait()
        n = 0
        while not stop.is_set():
            for _reply in get(key, consolidation=none, timeout=5.0):
                n += 1
                break
        counts[i] = n

    threads = [threading.Thread(target=querier, args=(i,)) for i in range(THREADS)]
    for t in threads:
        t.start()
    go.wait()
    t0 = time.perf_counter()
    time.sleep(THROUGHPUT_SECONDS)  # the measuring window, not synchronisation
    stop.set()
    for t in threads:
        t.join()
    return sum(counts) / (time.perf_counter() - t0)


def _pct(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def _alternate(measure: Callable[[str], object], keys: Iterable[str], rounds: int) -> None:
    for _ in range(rounds):
        for key in keys:
            measure(key)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        platform, db, (limb, origin, direction, size) = _databank(Path(tmp))
        name = load_platform(platform).name
        key = KEYS.pose(name, limb, origin, direction, size)
        keys = {
            "floor": FLOOR_PREFIX + key[len(KEYS.prefix) :],
            "databank": key,
            "subset": SUBSET_KEYS.prefix + key[len(KEYS.prefix) :],
        }
        endpoint = loopback_endpoint()
        reply_size = len(_encoded_reply(platform, db, key))
        server = subprocess.Popen(
            [sys.executable, __file__, endpoint, platform, db, str(reply_size)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT,
        )
        try:
            assert server.stdout is not None and server.stdout.readline().strip() == "ready"
            client = zenoh.open(session_config("peer", listen=[], connect=[endpoint]))
            try:
                for k in keys.values():
                    assert len(_wait_reply(client, k)) == reply_size
                print(f"pose query {key} ({name}, reply {reply_size} bytes) over loopback tcp "
                      "to a server process")
                _report(client, keys)
            finally:
                close_session(client)
        finally:
            server.communicate(timeout=30)


def _encoded_reply(platform: str, db: str, key: str) -> bytes:
    from kinesphere.protocol import encode

    pk = KEYS.parse_pose_key(key)
    return encode(Ecl.open(platform, db).query(pk.limb, pk.origin, pk.direction, float(pk.size)))


def _report(client: zenoh.Session, keys: dict[str, str]) -> None:
    """Latency, then throughput (variants in turn, round after round; the ratio is the median
    over rounds of variant / floor in the same round): both robust to the machine's drift."""
    labels = {
        "floor": "floor (bare echo queryable)",
        "databank": "databank (serves all known)",
        "subset": "databank (subset + catch-all)",
    }
    names, ks = list(keys), list(keys.values())
    _latencies(client, ks, WARMUP)
    lat = dict(zip(names, _latencies(client, ks, QUERIES), strict=True))
    print(f"  latency, {QUERIES} queries each, interleaved one by one; ratio to the floor "
          "(target p50 <= 1.20x)")
    f50, f99 = _pct(lat["floor"], 0.5), _pct(lat["floor"], 0.99)
    for name in names:
        p50, p99 = _pct(lat[name], 0.5), _pct(lat[name], 0.99)
        print(f"    {labels[name]:<31} p50 {p50:7.1f} us  p99 {p99:7.1f} us  "
              f"ratio p50 {p50 / f50:4.2f}x  p99 {p99 / f99:4.2f}x")
    qps: dict[str, list[float]] = {k: [] for k in keys.values()}
    _alternate(lambda k: qps[k].append(_throughput(client, k)), keys.values(),
               THROUGHPUT_ROUNDS)
    print(f"  throughput, {THREADS} concurrent queriers, {THROUGHPUT_ROUNDS} alternating rounds "
          f"of {THROUGHPUT_SECONDS:g} s")
    fq = qps[keys["floor"]]
    for name, k in keys.items():
        ratio = statistics.median(q / f for q, f in zip(qps[k], fq, strict=True))
        print(f"    {labels[name]:<31} {statistics.median(qps[k]):8,.0f} queries/s  "
              f"ratio {ratio:4.2f}")


if __name__ == "__main__":
    if len(sys.argv) in (5, 6):
        serve(sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), *sys.argv[5:])
    else:
        main()
