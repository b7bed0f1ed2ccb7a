"""Pose queries and commands across a mesh of ``kinesphere router`` processes, per hop count.

Three routers in a line, R0 - R1 - R2, each a separate process. Behind R0: one server process
with the real databank service and the floor (a bare Zenoh echo queryable replying a
pre-encoded payload of the databank's reply size, see ``bench_databank``), and, in this
process, a Baxter agent at 500 Hz real time with a bare subscriber beside it on its session.
Clients behind R0, R1 and R2 ask and command across 0, 1 and 2 router-to-router links
(1, 2 and 3 routers). Each figure has its baseline over the same hops in the same run: the
echo queryable for queries, a bare put -> callback for commands.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path

import zenoh

from bench.bench_agent import Floor, pct, put_to_moving, two_parts
from bench.bench_databank import (
    FLOOR_PREFIX,
    KEYS,
    WARMUP,
    _databank,
    _encoded_reply,
    _latencies,
    _wait_reply,
)
from kinesphere.errors import KinesphereError
from kinesphere.procs import Supervisor
from kinesphere.robots.agent.runtime import Agent, AgentOptions
from kinesphere.zconfig import close_session, free_port, open_session, session_config

ROOT = Path(__file__).resolve().parents[1]
HOPS = (0, 1, 2)
QUERIES = 2000
COMMANDS = 400


def _routers(sup: Supervisor) -> list[str]:
    """Start R0, R1 (linked to R0), R2 (linked to R1); their endpoints."""
    endpoints = [f"tcp/127.0.0.1:{free_port()}" for _ in HOPS]
    for i, ep in enumerate(endpoints):
        argv = ["router", "--listen", ep] + (["--link", endpoints[i - 1]] if i else [])
        sup.spawn(f"router-{i}", argv)
    return endpoints


def _client(endpoint: str, sup: Supervisor, timeout: float = 30.0) -> zenoh.Session:
    """A client of the router at ``endpoint``, retried while that router is starting."""
    deadline = time.monotonic() + timeout
    while True:
        sup.check()
        try:
            return open_session(session_config("client", listen=[], connect=[endpoint]))
        except KinesphereError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)  # nothing to wait on: the router process is not listening yet


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp, Supervisor(Path(tmp) / "logs") as sup:
        platform, db, (limb, origin, direction, size) = _databank(Path(tmp))
        key = KEYS.pose(platform, limb, origin, direction, size)
        floor_key = FLOOR_PREFIX + key[len(KEYS.prefix):]
        reply_size = len(_encoded_reply(platform, db, key))
        endpoints = _routers(sup)
        clients = [_client(ep, sup) for ep in endpoints]
        server = subprocess.Popen(
            [sys.executable, str(ROOT / "bench" / "bench_databank.py"), endpoints[0], platform,
             db, str(reply_size), "client"],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT)
        home = _client(endpoints[0], sup)
        try:
            assert server.stdout is not None and server.stdout.readline().strip() == "ready"
            for c in clients:  # every link is up once the far end's queries are answered
                for k in (key, floor_key):
                    assert len(_wait_reply(c, k, 30.0)) == reply_size
            print(f"router mesh R0 - R1 - R2 (separate processes, loopback tcp); databank, floor "
                  f"and a {platform} agent behind R0; clients behind R0, R1, R2")
            _queries(clients, key, floor_key, reply_size)
            agent = Agent(platform, "bench-mesh", home,
                          AgentOptions(speed=1.0, prefix=KEYS.prefix)).start()
            try:
                _commands(clients, home, agent)
            finally:
                agent.close()
        finally:
            for c in [*clients, home]:
                close_session(c)
            if server.stdin is not None:
                server.stdin.close()
            server.wait(timeout=30)


def _queries(clients: list[zenoh.Session], key: str, floor_key: str, size: int) -> None:
    print(f"  pose query round trip ({size}-byte reply), {QUERIES} queries per hop count, "
          "databank and floor interleaved one by one:")
    print(f"    {'links':<5} {'databank p50':>13} {'p99':>9} {'floor p50':>10} {'p99':>9} "
          f"{'ratio p50':>9} {'p99':>6}")
    for hops, c in zip(HOPS, clients, strict=True):
        _latencies(c, [key, floor_key], WARMUP)
        db, floor = _latencies(c, [key, floor_key], QUERIES)
        _row(hops, db, floor)


def _commands(clients: list[zenoh.Session], home: zenoh.Session, agent: Agent) -> None:
    parts = two_parts(agent)
    print(f"  command latency, {COMMANDS} commands per hop count: agent put -> first setpoint "
          "toward the target (cached poses, 500 Hz) against a bare put -> callback on the "
          "agent's session, interleaved:")
    print(f"    {'links':<5} {'agent p50':>13} {'p99':>9} {'floor p50':>10} {'p99':>9} "
          f"{'ratio p50':>9} {'p99':>6}")
    seq = 1
    for hops, c in zip(HOPS, clients, strict=True):
        floor = Floor(c, home, key=f"bench/floor/{hops}")
        lat = put_to_moving(agent, c, parts, COMMANDS, seq0=seq, floor=floor)
        floor.close()
        seq += COMMANDS + 2
        _row(hops, lat, floor.values)
    print(f"    ({agent.stats.slips} control-loop slips)")


def _row(hops: int, values: list[float], floor: list[float]) -> None:
    v50, v99, f50, f99 = pct(values, 50), pct(values, 99), pct(floor, 50), pct(floor, 99)
    print(f"    {hops:<5} {v50:11.1f}us {v99:7.1f}us {f50:8.1f}us {f99:7.1f}us "
          f"{v50 / f50:8.2f}x {v99 / f99:5.2f}x", flush=True)


if __name__ == "__main__":
    main()
