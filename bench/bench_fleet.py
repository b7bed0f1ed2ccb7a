"""Fleet host (``kinesphere fleet``, ``kinesphere agent --robot P:ID ...``): the cost per robot
against the bare ``mj_step`` of the same bodies, what each choice bought, and how many robots
keep real time per number of worker processes.

1. Cost per robot vs N: N mixed-platform robots (baxter, nao, youbot, packbot, khepera in turn)
   in one fleet loop in this process (what one worker runs), unpaced, the physics on the loop's
   thread alone, every robot moving (a new pose every 0.5 s of robot time). Baseline: the bare
   ``mj_step`` of the same bodies: copies of their MjData taken at the same step, stepped in a
   plain loop, in chunks interleaved with the ticks (so both see the same machine). Each side
   is the median over state periods (10 ticks) of the mean tick or step: since 2026-12-06 a
   fleet publishes its states in groups, in a few ticks of each period, and the median single
   tick (the measure before) would leave those ticks out.
2. What each choice bought at N = 48, each against its alternative in the same run, ticked in
   alternating chunks: the batching (followed trajectories, lean steps) against every robot's
   whole cycle with its own Ruckig steps; a physics helper thread; shared ``MjModel`` objects;
   then per step: the followers against Ruckig's ``update`` per DoF count, the hard stops of
   all bodies at once against one body at a time, the stepper against MuJoCo's threaded
   ``rollout``.
3. Real time per worker count: ``kinesphere agent --robot ... --workers W`` at 500 Hz with the
   robots moving, judged as ``bench_agent``'s scale test judges processes and threads (the worst
   robot's state rate over 3 s >= 98 %), with the bare ``mj_step`` of the same bodies measured
   after each count (the host's phase: its speed moves by up to 2x between runs).

Part 1 ends with the Python function calls per robot per tick at N = 48 (cProfile over
:data:`RETARGET` ticks, robots moving): a count the machine's load does not change, so a change
to the per-robot work shows in it even when the timings are noisy. (``mj_step`` itself is not
among them since the stepper calls it from C, bound to each body: one call per robot and tick
that counts before 2026-12-06 included.) Then the physics inside the
tick at N = 48 against two bare baselines: the table's (copies taken at the start of each chunk,
which hold their setpoints and settle) and copies taken from the bodies after every tick (the
states the fleet stepped): how much of the ratio is physics of moving bodies, not Python.

``BENCH_FLEET_PARTS=13 python -m bench fleet`` runs only the parts named (default ``123``).
"""

from __future__ import annotations

import copy
import cProfile
import logging
import os
import pstats
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager

import mujoco
import numpy as np
import zenoh
from mujoco import rollout

from bench.bench_agent import (
    PLATFORMS,
    command,
    databank,
    fleet_parts,
    pct,
    realtime_share,
    state_stamps,
)
from kinesphere import zconfig
from kinesphere.protocol import SpatialCommand
from kinesphere.robots.agent.bodies import make_body
from kinesphere.robots.agent.body import Body
from kinesphere.robots.agent.fleet import FleetHost, RobotSpec
from kinesphere.robots.agent.follow import Followers
from kinesphere.robots.agent.mujoco_body import HardStops, MujocoBody
from kinesphere.robots.agent.otg import Otg
from kinesphere.robots.agent.runtime import AgentOptions
from kinesphere.robots.agent.stepper import Stepper, default_helpers

COUNTS = (1, 8, 16, 24, 32, 48, 64)
CHUNK = 25
"""Ticks (then as many bare steps) per chunk of the interleaved measurements."""
CHUNKS = 40
RETARGET = 250  # ticks between new poses: 0.5 s of robot time at 500 Hz
N_ABLATE = 48
WORKERS = (1, 2)
REALTIME = (16, 32, 48, 64, 80, 96)
DOFS = (2, 5, 9, 14, 26)
Parts = dict[str, list[SpatialCommand]]


def robots(n: int, tag: str) -> list[RobotSpec]:
    return [RobotSpec(PLATFORMS[i % len(PLATFORMS)], f"{tag}-{n}-{i}") for i in range(n)]


class Moving:
    """A fleet in this process whose robots get a new pose every :data:`RETARGET` ticks."""

    def __init__(self, fleet: FleetHost, parts: Parts) -> None:
        self.fleet, self.parts, self.k = fleet, parts, 0
        for k in range(2):  # both poses resolved and cached: no tick waits on the network
            for a in fleet.agents:
                a.receive(command(k + 1, parts[a.platform][k]))
            deadline = time.monotonic() + 30
            while not all(len(a.conduct.latencies) > k for a in fleet.agents):
                fleet.tick()
                if time.monotonic() > deadline:
                    raise RuntimeError("poses were not resolved within 30 s")

    def ticks(self, n: int) -> list[float]:
        """Seconds per tick for ``n`` ticks."""
        clock, out = time.perf_counter, []
        for _ in range(n):
            if self.k % RETARGET == 0:
                pose = (self.k // RETARGET) % 2
                for a in self.fleet.agents:
                    a.receive(command(10 + self.k, self.parts[a.platform][pose]))
            self.k += 1
            t0 = clock()
            self.fleet.tick()
            out.append(clock() - t0)
        return out


@contextmanager
def moving(endpoint: str, n: int, parts: Parts, tag: str, helpers: int = 0,
           batched: bool = True, tweak: Callable[[FleetHost], None] | None = None,
           ) -> Iterator[Moving]:
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        fleet = FleetHost(robots(n, tag), s, AgentOptions(speed=0.0), helpers=helpers,
                      batched=batched)
        try:
            fleet.declare()
            if tweak is not None:
                tweak(fleet)
            yield Moving(fleet, parts)
        finally:
            fleet.close()


class Bare:
    """The bare ``mj_step`` of a fleet's bodies: copies of their MjData, taken again at the
    start of each chunk (so they step from the same state with the same setpoints)."""

    def __init__(self, fleet: FleetHost) -> None:
        self.bodies = [a.controller.body for a in fleet.agents]
        assert all(isinstance(b, MujocoBody) for b in self.bodies)
        self.copies = [(b.model, copy.copy(b.data)) for b in self.bodies]  # type: ignore[attr-defined]

    def take(self) -> None:
        """The copies as the bodies are now."""
        for (m, d), b in zip(self.copies, self.bodies, strict=True):
            mujoco.mj_copyData(d, m, b.data)  # type: ignore[attr-defined]

    def steps(self, n: int) -> list[float]:
        """Seconds per step of all copies for ``n`` steps from the bodies' state now."""
        self.take()
        return self.steps_as_taken(n)

    def steps_as_taken(self, n: int) -> list[float]:
        clock, out = time.perf_counter, []
        for _ in range(n):
            t0 = clock()
            for m, d in self.copies:
                mujoco.mj_step(m, d)
            out.append(clock() - t0)
        return out


PERIOD = 10
"""Ticks per state period (500 Hz control, 50 Hz states)."""


def per_period(costs: Sequence[float]) -> float:
    """The median over consecutive runs of :data:`PERIOD` costs of their mean: a fleet publishes
    its states in groups (``fleet.state_steps``), so the median single tick would leave out the
    ticks that compose and put them; any :data:`PERIOD` consecutive ticks hold every group once."""
    a = np.asarray(costs)
    k = a.size // PERIOD * PERIOD
    return float(np.median(a[:k].reshape(-1, PERIOD).mean(axis=1)))


def curve(endpoint: str, parts: Parts) -> None:
    print(f"cost per robot vs N: one fleet loop (one worker's) in this process, unpaced, physics "
          f"on the loop's thread, robots moving; over {CHUNKS * CHUNK} ticks the median state "
          f"period's mean tick ({PERIOD} ticks), against the bare mj_step of the same bodies, "
          f"interleaved in chunks of {CHUNK}:")
    print(f"  {'N':>3} {'tick':>9} {'per robot':>10} {'bare mj_step':>13} {'per body':>9} "
          f"{'ratio':>6}")
    for n in COUNTS:
        with moving(endpoint, n, parts, "c") as m:
            bare = Bare(m.fleet)
            ticks, steps = [], []
            for _ in range(CHUNKS):
                ticks += m.ticks(CHUNK)
                steps += bare.steps(CHUNK)
        t, b = per_period(ticks), per_period(steps)
        print(f"  {n:>3} {t * 1e3:6.3f} ms {t / n * 1e6:7.1f} us {b * 1e3:10.3f} ms "
              f"{b / n * 1e6:6.1f} us {t / b:5.2f}x", flush=True)
    print("  (ratio: the cost per robot against the bare mj_step per body; a 500 Hz loop has "
          "2 ms per tick)")
    print(f"  python calls per robot per tick at N = {N_ABLATE} (cProfile, {RETARGET} ticks, "
          f"robots moving; the load does not change it): {calls_per_robot(endpoint, parts):.1f}",
          flush=True)
    inside, chunked, same = physics_gap(endpoint, parts)
    print(f"  physics inside the tick at N = {N_ABLATE}: {inside * 1e3:.3f} ms, "
          f"{inside / chunked:.2f}x the bare mj_step of the chunk's copies, {inside / same:.2f}x "
          "that of copies taken from the bodies at every tick (a chunk's copies hold their "
          "setpoints and settle, cheaper physics than moving bodies: part of each ratio above is "
          "not Python)", flush=True)


def physics_gap(endpoint: str, parts: Parts, n: int = N_ABLATE) -> tuple[float, float, float]:
    """Median seconds per tick of the fleet's physics (its stepper's share in the tick), of the
    bare mj_step of copies taken at the start of each chunk (the table's baseline), and of
    copies taken from the bodies after every tick (the same states the fleet stepped)."""
    with moving(endpoint, n, parts, "gap") as m:
        fleet, inside = m.fleet, []
        launch = fleet.stepper.launch

        def timed(bodies: Sequence[Body], share: bool = False) -> None:
            t0 = time.perf_counter()
            launch(bodies, share)
            inside.append(time.perf_counter() - t0)

        fleet.stepper.launch = timed  # type: ignore[method-assign]
        bare, chunked, same = Bare(fleet), [], []
        for _ in range(CHUNKS):
            for _ in range(CHUNK):
                m.ticks(1)
                fleet.complete()
                bare.take()
                same += bare.steps_as_taken(1)
            chunked += bare.steps(CHUNK)
    return pct(inside, 50), pct(chunked, 50), pct(same, 50)


def calls_per_robot(endpoint: str, parts: Parts, n: int = N_ABLATE) -> float:
    """Function calls (Python's and builtins') per robot per tick of a moving fleet of ``n``."""
    with moving(endpoint, n, parts, "calls") as m:
        m.ticks(RETARGET)  # past the first plans
        profile = cProfile.Profile()
        profile.enable()
        m.ticks(RETARGET)
        profile.disable()
    return float(pstats.Stats(profile).total_calls) / n / RETARGET  # type: ignore[attr-defined]


def private_models(fleet: FleetHost) -> None:
    for a in fleet.agents:
        body = a.controller.body
        assert isinstance(body, MujocoBody)
        body.model = copy.copy(body.model)  # a real copy of the compiled model (mj_copyModel)


def ablations(endpoint: str, parts: Parts) -> None:
    n = N_ABLATE
    print(f"what each choice bought, {n} robots moving, unpaced, one loop (median / p99 tick, "
          f"the alternative in the same run, chunks of {CHUNK} ticks taken in turn):")
    Factory = Callable[[str], AbstractContextManager[Moving]]
    rows: list[tuple[str, Factory, str, Factory]] = [
        ("batched (followers, lean steps)", lambda t: moving(endpoint, n, parts, t),
         "each robot's whole cycle", lambda t: moving(endpoint, n, parts, t, batched=False)),
        ("physics: loop + 1 helper thread", lambda t: moving(endpoint, n, parts, t, helpers=1),
         "loop thread only", lambda t: moving(endpoint, n, parts, t)),
        ("shared MjModel per platform", lambda t: moving(endpoint, n, parts, t),
         "a private copy per robot", lambda t: moving(endpoint, n, parts, t,
                                                       tweak=private_models)),
    ]
    for name, ours_fleet, alt_name, alt_fleet in rows:
        ours: list[float] = []
        alt: list[float] = []
        with ours_fleet("a1") as a, alt_fleet("a0") as b:
            for _ in range(CHUNKS):
                ours += a.ticks(CHUNK)
                alt += b.ticks(CHUNK)
        o = (pct(ours, 50), pct(ours, 99))
        x = (pct(alt, 50), pct(alt, 99))
        print(f"  {name:<32} {o[0] * 1e3:6.3f} / {o[1] * 1e3:6.3f} ms   vs {alt_name:<25} "
              f"{x[0] * 1e3:6.3f} / {x[1] * 1e3:6.3f} ms   ratio p50 {o[0] / x[0]:4.2f}x  "
              f"p99 {o[1] / x[1]:4.2f}x", flush=True)
    following()
    hard_stops(n)
    batched_physics(n)


def following(robots: int = 48) -> None:
    """Per step of a moving robot's joints: ``robots`` generators of a DoF count followed at
    once, against each taking its own step through Ruckig's ``update``."""
    print(f"  joint trajectories, per robot and step, {robots} robots moving (followers at "
          "once vs Ruckig's update each):")
    for n in DOFS:
        alone = [Otg(n, 0.002, [1.0] * n, [5.0] * n, [50.0] * n, np.zeros(n))
                 for _ in range(robots)]
        followed = [Otg(n, 0.002, [1.0] * n, [5.0] * n, [50.0] * n, np.zeros(n))
                    for _ in range(robots)]
        followers = Followers(followed, 0.002)
        costs: dict[bool, list[float]] = {False: [], True: []}
        for k in range(400):
            if k % 100 == 0:
                for otg in alone + followed:
                    otg.go_to(np.full(n, 0.5 * (1 + (k // 100) % 2)))
                for otg in alone + followed:
                    otg.step()  # Ruckig plans (both sides)
                continue
            t0 = time.perf_counter()
            for otg in alone:
                otg.step()
            t1 = time.perf_counter()
            followers.advance()
            for otg in followed:
                otg.step()
            t2 = time.perf_counter()
            costs[False].append(t1 - t0)
            costs[True].append(t2 - t1)
        r, f = (pct(costs[x], 50) / robots * 1e6 for x in (False, True))
        print(f"    {n:>2} DoF: {f:5.2f} us vs {r:5.2f} us  ({f / r:4.2f}x)")


def hard_stops(n: int) -> None:
    bodies = [make_body("mujoco", PLATFORMS[i % len(PLATFORMS)], 0.002) for i in range(n)]
    mbodies = [b for b in bodies if isinstance(b, MujocoBody)]
    stops = HardStops(mbodies)

    def each() -> None:
        for b in mbodies:
            b.hard_stop()

    at_once, one_by_one = [], []
    for _ in range(3):
        at_once.append(timed(stops.apply))
        one_by_one.append(timed(each))
    o, e = min(at_once), min(one_by_one)
    print(f"  hard stops of {n} bodies: at once {o * 1e6:.1f} us vs one body at a time "
          f"{e * 1e6:.1f} us ({o / e:.2f}x)")


def timed(fn: Callable[[], None], n: int = 300) -> float:
    costs = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        costs.append(time.perf_counter() - t0)
    return pct(costs, 50)


def batched_physics(n: int) -> None:
    """Physics alone for N mixed bodies: the stepper (one mj_step per body, a helper thread)
    against MuJoCo's threaded rollout, one call per platform with the state copied in and out
    (what a fleet host would have to do to use it)."""
    bodies = [make_body("mujoco", PLATFORMS[i % len(PLATFORMS)], 0.002) for i in range(n)]
    mbodies = [b for b in bodies if isinstance(b, MujocoBody)]
    stepper = Stepper(max(1, default_helpers()))
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    groups: dict[int, list[MujocoBody]] = {}
    for b in mbodies:
        groups.setdefault(id(b.model), []).append(b)
    buffers = {}
    for k, g in groups.items():
        m = g[0].model
        size = mujoco.mj_stateSize(m, spec)
        buffers[k] = (np.zeros((len(g), size)), np.zeros((len(g), 1, m.nu)),
                      np.zeros((len(g), 1, size)), [mujoco.MjData(m) for _ in range(2)])

    def stepped() -> None:
        stepper.simulate(bodies)

    def rolled(runner: rollout.Rollout) -> None:
        for k, g in groups.items():
            state, ctrl, out, scratch = buffers[k]
            m = g[0].model
            for i, b in enumerate(g):
                mujoco.mj_getState(m, b.data, state[i], spec)
                ctrl[i, 0] = b.data.ctrl
            runner.rollout(m, scratch, state, ctrl, state=out)
            for i, b in enumerate(g):
                mujoco.mj_setState(m, b.data, out[i, 0], spec)

    with rollout.Rollout(nthread=stepper.threads) as runner:
        ours, batched = [], []
        for _ in range(3):  # alternate, so drift in the machine's load hits both
            ours.append(timed(stepped))
            batched.append(timed(lambda: rolled(runner)))
    stepper.close()
    o, r = min(ours), min(batched)
    print(f"  physics of {n} bodies: stepper {o * 1e3:.3f} ms ({o / n * 1e6:.1f} us/body, "
          f"{stepper.threads} threads) vs rollout batched per platform {r * 1e3:.3f} ms "
          f"({r / n * 1e6:.1f} us/body, state copied in and out): ratio {o / r:.2f}x")


def bare_per_body(n: int) -> tuple[float, float]:
    """Microseconds of one bare ``mj_step`` per body for N fresh mixed bodies, and Baxter's."""
    bodies = [make_body("mujoco", PLATFORMS[i % len(PLATFORMS)], 0.002) for i in range(n)]
    pairs = [(b.model, b.data) for b in bodies if isinstance(b, MujocoBody)]
    for _ in range(200):  # past the first steps of settling
        for m, d in pairs:
            mujoco.mj_step(m, d)

    def all_bodies() -> None:
        for m, d in pairs:
            mujoco.mj_step(m, d)

    m0, d0 = pairs[0]
    return timed(all_bodies, 200) / n * 1e6, timed(lambda: mujoco.mj_step(m0, d0), 300) * 1e6


def realtime(endpoint: str, hub: zenoh.Session) -> None:
    print("real time: a fleet host at 500 Hz, mixed platforms, robots moving, per number of "
          "worker processes; 'keeps up' = the worst robot's state rate >= 98% of real time over "
          "3 s; then the bare mj_step of the same bodies (the host's phase):")
    with state_stamps(hub) as states:
        for w in WORKERS:
            best = 0
            for n in REALTIME:
                ids = [f"rt-{w}-{n}-{i}" for i in range(n)]
                platforms = [PLATFORMS[i % len(PLATFORMS)] for i in range(n)]
                frac = realtime_share("fleet", endpoint, hub, ids, platforms, states, w)
                per_body, baxter = bare_per_body(n)
                print(f"  {w} worker{'s' if w > 1 else ' '} x{n:<3}: worst robot at "
                      f"{frac * 100:5.1f}% of real time"
                      f"{'' if frac >= 0.98 else '  <- falls behind (twice)':<26}"
                      f" bare mj_step {per_body:5.1f} us/body (Baxter {baxter:4.1f} us)",
                      flush=True)
                if frac < 0.98:
                    break
                best = n
            more = " (or more: the largest count tried)" if best == REALTIME[-1] else ""
            print(f"  => {best} robots keep real time on a fleet host of {w} worker"
                  f"{'s' if w > 1 else ''}{more}", flush=True)


def main() -> None:
    logging.getLogger("kinesphere.robots.agent").setLevel(logging.ERROR)
    with zconfig.loopback_hub() as (hub, endpoint), databank(endpoint, hub):
        parts = fleet_parts(endpoint)
        wanted = os.environ.get("BENCH_FLEET_PARTS", "123")
        if "1" in wanted:
            curve(endpoint, parts)
        if "2" in wanted:
            ablations(endpoint, parts)
        if "3" in wanted:
            realtime(endpoint, hub)


if __name__ == "__main__":
    main()
