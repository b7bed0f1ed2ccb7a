"""Fleet host (``kinesphere fleet``, ``kinesphere agent --robot P:ID ...``): how the cost per
robot grows with N, what each design choice bought, and how many robots keep real time.

1. Cost curve: N mixed-platform robots (baxter, nao, youbot, packbot, khepera in turn) in a
   fleet host in this process, unpaced, every robot moving (a new pose every 0.5 s of robot
   time): median tick cost, per robot, with the physics on the loop's thread alone and with a
   helper thread. Baseline: the bare ``mj_step`` of the same bodies, measured in the same run.
2. What each choice bought, at N = 48, each against its alternative in the same run: the
   physics helper thread; shared ``MjModel`` objects (against a private copy per robot);
   state publishing spread over the ticks (against every robot publishing in the same tick);
   Ruckig's cost per DoF (against ``mj_step``: is batching it worth anything?); one ``mj_step``
   per body on the stepper against MuJoCo's threaded ``rollout`` batched per platform.
3. Real time: a fleet host process at 500 Hz with robots moving, as ``bench_agent``'s scale
   test judges processes and threads: the worst robot's state rate over 3 s >= 98 %.
"""

from __future__ import annotations

import copy
import logging
import time
from collections.abc import Callable

import mujoco
import numpy as np
from mujoco import rollout

from bench.bench_agent import (
    PLATFORMS,
    command,
    databank,
    fleet_parts,
    pct,
    scale,
)
from kinesphere import zconfig
from kinesphere.protocol import SpatialCommand
from kinesphere.robots.agent.bodies import make_body
from kinesphere.robots.agent.fleet import FleetHost, RobotSpec
from kinesphere.robots.agent.mujoco_body import MujocoBody
from kinesphere.robots.agent.otg import Otg
from kinesphere.robots.agent.runtime import AgentOptions
from kinesphere.robots.agent.stepper import Stepper, default_helpers

COUNTS = (1, 8, 16, 24, 32, 48, 64)
TICKS = 1000
RETARGET = 250  # ticks between new poses: 0.5 s of robot time at 500 Hz
N_ABLATE = 48
REALTIME = (("fleet", (16, 32, 40, 48, 56, 64)),)
DOFS = (2, 5, 9, 14, 26)


def robots(n: int, tag: str) -> list[RobotSpec]:
    return [RobotSpec(PLATFORMS[i % len(PLATFORMS)], f"{tag}-{n}-{i}") for i in range(n)]


def warm(fleet: FleetHost, parts: dict[str, list[SpatialCommand]]) -> None:
    """Both poses of every robot resolved and cached: the loop never waits on the network."""
    for k in range(2):
        for a in fleet.agents:
            a.receive(command(k + 1, parts[a.platform][k]))
        deadline = time.monotonic() + 30
        while not all(len(a.conduct.latencies) > k for a in fleet.agents):
            fleet.tick()
            if time.monotonic() > deadline:
                raise RuntimeError("poses were not resolved within 30 s")


def tick_costs(fleet: FleetHost, parts: dict[str, list[SpatialCommand]], ticks: int = TICKS,
               seq0: int = 10) -> list[float]:
    """Seconds per tick, robots retargeted every :data:`RETARGET` ticks."""
    clock = time.perf_counter
    out = []
    for k in range(ticks):
        if k % RETARGET == 0:
            for a in fleet.agents:
                a.receive(command(seq0 + k, parts[a.platform][(k // RETARGET) % 2]))
        t0 = clock()
        fleet.tick()
        out.append(clock() - t0)
    return out


def bare_mj_step(n: int) -> float:
    """Seconds per tick of ``mj_step`` alone for the same N bodies, serially."""
    bodies = [mujoco_body(PLATFORMS[i % len(PLATFORMS)]) for i in range(n)]
    costs = []
    for _ in range(300):
        t0 = time.perf_counter()
        for b in bodies:
            mujoco.mj_step(b.model, b.data)
        costs.append(time.perf_counter() - t0)
    return pct(costs, 50)


def mujoco_body(platform: str) -> MujocoBody:
    body = make_body("mujoco", platform, 0.002)
    assert isinstance(body, MujocoBody)
    return body


def mj_step_us(platform: str) -> float:
    """Median microseconds of one ``mj_step`` of ``platform``'s body."""
    body = mujoco_body(platform)
    costs = []
    for _ in range(300):
        t0 = time.perf_counter()
        mujoco.mj_step(body.model, body.data)
        costs.append(time.perf_counter() - t0)
    return pct(costs, 50) * 1e6


def run(endpoint: str, n: int, helpers: int, parts: dict[str, list[SpatialCommand]],
        tag: str, tweak: Callable[[FleetHost], None] | None = None) -> list[float]:
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        fleet = FleetHost(robots(n, tag), s, AgentOptions(speed=0.0), helpers=helpers)
        try:
            fleet.declare()
            if tweak is not None:
                tweak(fleet)
            warm(fleet, parts)
            return tick_costs(fleet, parts)
        finally:
            fleet.close()


def curve(endpoint: str, parts: dict[str, list[SpatialCommand]]) -> None:
    h = default_helpers()
    print(f"cost per robot vs N: fleet host in this process, unpaced, robots moving; median "
          f"tick over {TICKS} ticks; physics on the loop's thread alone / with {h} helper(s):")
    print(f"  {'N':>3} {'tick, 0 helpers':>16} {'per robot':>10} {f'tick, {h} helper':>16} "
          f"{'per robot':>10} {'bare mj_step':>13} {'ratio':>6}")
    for n in COUNTS:
        serial = pct(run(endpoint, n, 0, parts, "c0"), 50)
        helped = pct(run(endpoint, n, h, parts, "ch"), 50)
        bare = bare_mj_step(n)
        print(f"  {n:>3} {serial * 1e3:13.3f} ms {serial / n * 1e6:7.1f} us "
              f"{helped * 1e3:13.3f} ms {helped / n * 1e6:7.1f} us {bare * 1e3:10.3f} ms "
              f"{helped / bare:5.2f}x", flush=True)
    print("  (ratio: the tick with helpers against the bare mj_step of the same bodies; "
          "a 500 Hz loop has 2 ms per tick)")


def private_models(fleet: FleetHost) -> None:
    for a in fleet.agents:
        body = a.controller.body
        assert isinstance(body, MujocoBody)
        body.model = copy.copy(body.model)  # a real copy of the compiled model (mj_copyModel)


def aligned_states(fleet: FleetHost) -> None:
    for a in fleet.agents:
        a._phase = 0  # every robot publishes in the same tick


def ablations(endpoint: str, parts: dict[str, list[SpatialCommand]]) -> None:
    n, h = N_ABLATE, max(1, default_helpers())
    print(f"what each choice bought, {n} robots, unpaced, robots moving (median / p99 / max "
          "tick; alternative in the same run):")
    rows = [
        ("physics: loop thread + helper", run(endpoint, n, h, parts, "a1"),
         "loop thread only", run(endpoint, n, 0, parts, "a0")),
        ("shared MjModel per platform", run(endpoint, n, h, parts, "m1"),
         "a private copy per robot", run(endpoint, n, h, parts, "m0", private_models)),
        ("state spread over the ticks", run(endpoint, n, h, parts, "s1"),
         "all states in one tick", run(endpoint, n, h, parts, "s0", aligned_states)),
    ]
    for name, ours, alt_name, alt in rows:
        o = (pct(ours, 50), pct(ours, 99), max(ours))
        a = (pct(alt, 50), pct(alt, 99), max(alt))
        print(f"  {name:<30} {o[0] * 1e3:6.3f} / {o[1] * 1e3:6.3f} / {o[2] * 1e3:6.3f} ms   "
              f"vs {alt_name:<24} {a[0] * 1e3:6.3f} / {a[1] * 1e3:6.3f} / {a[2] * 1e3:6.3f} ms"
              f"   ratio p50 {o[0] / a[0]:4.2f}x  p99 {o[1] / a[1]:4.2f}x", flush=True)
    ruckig_per_dof()
    batched_physics(n)


def ruckig_per_dof() -> None:
    """Ruckig through the agent's wrapper: a step while following, and the step after a new
    target (which recomputes the profile), per DoF count, against the mean ``mj_step``."""
    mj = float(np.mean([mj_step_us(p) for p in PLATFORMS]))
    print(f"  Ruckig per step (follow / retarget), against the mean mj_step of the platforms "
          f"({mj:.1f} us):")
    for n in DOFS:
        otg = Otg(n, 0.002, [1.0] * n, [5.0] * n, [50.0] * n, np.zeros(n))
        follow, retarget = [], []
        for k in range(400):
            if k % 100 == 0:
                otg.go_to(np.full(n, 0.5 * (1 + (k // 100) % 2)))
            t0 = time.perf_counter()
            otg.step()
            dt = (time.perf_counter() - t0) * 1e6
            (retarget if k % 100 == 0 else follow).append(dt)
        f50, r50 = pct(follow, 50), pct(retarget, 50)
        print(f"    {n:>2} DoF: {f50:5.1f} / {r50:5.1f} us  ({f50 / mj * 100:4.1f}% / "
              f"{r50 / mj * 100:4.1f}% of an mj_step)")


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

    def timed(fn: Callable[[], None]) -> float:
        costs = []
        for _ in range(300):
            t0 = time.perf_counter()
            fn()
            costs.append(time.perf_counter() - t0)
        return pct(costs, 50)

    with rollout.Rollout(nthread=stepper.threads) as runner:
        ours, batched = [], []
        for _ in range(3):  # alternate, so drift in the machine's load hits both
            ours.append(timed(stepped))
            batched.append(timed(lambda: rolled(runner)))
    stepper.close()
    o, b = min(ours), min(batched)
    print(f"  physics of {n} bodies: stepper {o * 1e3:.3f} ms ({o / n * 1e6:.1f} us/body, with "
          f"the hard stops) vs rollout batched per platform {b * 1e3:.3f} ms "
          f"({b / n * 1e6:.1f} us/body, state copied in and out): ratio {o / b:.2f}x")


def main() -> None:
    logging.getLogger("kinesphere.robots.agent").setLevel(logging.ERROR)
    with zconfig.loopback_hub() as (hub, endpoint), databank(endpoint, hub):
        parts = fleet_parts(endpoint)
        curve(endpoint, parts)
        ablations(endpoint, parts)
        scale(endpoint, hub, REALTIME)


if __name__ == "__main__":
    main()
