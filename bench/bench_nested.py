"""Nested parts (an upper arm and a forearm pointed together): their cost at query time against
a plain pose query in the same run, and what storing them as rows instead would cost.

The real databank (``kinesphere databank serve``, the shipped databanks) runs in a subprocess;
this process asks it over loopback, per platform (Baxter, NAO):

* plain: a stored pose key, answered from the service's cache after its first answer (the
  baseline);
* first nested: the first nested compound a fresh databank answers (the body's model compiled,
  the solver set up);
* nested cold: upper arm + forearm pairs never asked before (the solver's worker);
* nested cached: the same pairs again (the service's reply cache).

Then the alternative: the rows a databank would store to
answer every nested pair and size from stored rows, their bytes at the shipped databanks' bytes
per row, and the generation time at the measured solve time.
"""

from __future__ import annotations

import sqlite3
import statistics
import time

import zenoh

from bench.bench_agent import databank
from kinesphere import zconfig
from kinesphere.keyexpr import Keys
from kinesphere.laban import Direction
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import CompoundRequest, Pose, SpatialCommand, encode
from kinesphere.query import get_one
from kinesphere.services.ecl.store import default_db_path
from kinesphere.vocabulary import vocabulary

KEYS = Keys("knest")
PLATFORMS = ("baxter", "nao")
DIRECTIONS = [d for d in Direction if d.horizontal.value != "place"]
PAIRS = [(DIRECTIONS[i], DIRECTIONS[(7 * i + 5) % 24]) for i in range(24)]
PLAIN_QUERIES = 200
TIMEOUT_S = 30.0


def _ms(session: zenoh.Session, key: str, payload: bytes | None = None) -> tuple[float, Pose | str]:
    t0 = time.perf_counter()
    try:
        pose: Pose | str = get_one(session, key, Pose, payload, timeout=TIMEOUT_S, retry=True)
    except Exception as exc:  # a refusal (direction_unavailable) is an answer too
        pose = str(exc)
    return (time.perf_counter() - t0) * 1000.0, pose


def _nested(d1: Direction, d2: Direction) -> bytes:
    return encode(CompoundRequest(parts=[
        SpatialCommand("right_upper_arm", "right_shoulder", d1.slug, 3),
        SpatialCommand("right_forearm", "right_elbow", d2.slug, 3)]))


def _stats(values: list[float]) -> str:
    ordered = sorted(values)
    p90 = ordered[min(len(ordered) - 1, int(0.9 * len(ordered)))]
    return f"median {statistics.median(values):7.2f}  p90 {p90:7.2f}  max {max(values):7.2f}"


def _platform(session: zenoh.Session, name: str) -> float:
    """Time one platform's queries; the median cold nested solve in ms."""
    plain_key = KEYS.pose(name, "right_arm", "right_shoulder", "left-high", 3)
    compound = KEYS.compound(name)
    _ms(session, plain_key)
    first, _ = _ms(session, compound, _nested(Direction.FORWARD_HIGH, Direction.FORWARD_HIGH))
    cold, cached, plain = [], [], []
    served = refused = 0
    for d1, d2 in PAIRS:
        t, answer = _ms(session, compound, _nested(d1, d2))
        cold.append(t)
        served += isinstance(answer, Pose)
        refused += not isinstance(answer, Pose)
    for d1, d2 in PAIRS:  # the same again, interleaved with plain queries
        cached.append(_ms(session, compound, _nested(d1, d2))[0])
        for _ in range(PLAIN_QUERIES // len(PAIRS)):
            plain.append(_ms(session, plain_key)[0])
    base = statistics.median(plain)
    print(f"{name}: {served} pairs served, {refused} refused (a segment more than 45 degrees "
          "off at best, or toppling)")
    print(f"  plain pose (cached)    {_stats(plain)} ms")
    print(f"  first nested (cold db) {first:7.1f} ms = {first / base:6.0f}x plain")
    print(f"  nested, new pair       {_stats(cold)} ms; median "
          f"{statistics.median(cold) / base:.0f}x plain")
    print(f"  nested, same again     {_stats(cached)} ms; median "
          f"{statistics.median(cached) / base:.2f}x plain")
    return statistics.median(cold)


def _stored_alternative(solve_ms: dict[str, float]) -> None:
    """Rows a databank would need to answer every nested pair from storage."""
    sizes, pulls = 3, 26
    for name in PLATFORMS:
        e = load_platform(name).eurdf
        chains: dict[int, int] = {}
        for p in e.limbs:
            chains[p.index[0]] = max(chains.get(p.index[0], 0), p.index[1])
        pairs = sum(depth * (depth - 1) // 2 for depth in chains.values())  # limb + inner limb
        cuts = len({(w.label, w.end) for w in vocabulary(e) if w.end})  # upper arms, thighs
        rows = pairs * (pulls * sizes) ** 2 + cuts * pulls * sizes  # (three parts: more)
        db = default_db_path(name)
        with sqlite3.connect(f"file:{db}?mode=ro", uri=True) as conn:
            stored = conn.execute("SELECT COUNT(*) FROM pose").fetchone()[0]
        per_row = db.stat().st_size / max(stored, 1)
        hours = rows * solve_ms[name] / 1000 / 3600
        print(f"{name}: stored rows instead: {pairs} nested pairs + {cuts} cut limbs -> at least "
              f"{rows:,} rows ({rows / max(stored, 1):.0f}x the {stored} rows shipped), "
              f"~{rows * per_row / 2**20:.0f} MiB at {per_row:.0f} B/row, ~{hours:.1f} h to "
              f"generate at {solve_ms[name]:.0f} ms a solve; at query time: nothing stored")


def main() -> None:
    with zconfig.loopback_hub() as (hub, endpoint), databank(endpoint, hub, KEYS):
        solve_ms = {name: _platform(hub, name) for name in PLATFORMS}
    _stored_alternative(solve_ms)


if __name__ == "__main__":
    main()
