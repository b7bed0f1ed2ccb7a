"""A fleet host's per-robot work done for all robots at once: trajectories followed on arrays
(``follow.py``), hard stops in one comparison (``HardStops``), and a lean step for a robot with
nothing to react to (``Agent.needs_cycle``).

Each is checked against what it replaces: Ruckig's own ``update`` step by step, the per-body
hard stop, and a lone agent's whole cycle given the same commands at the same steps.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import mujoco
import numpy as np
import pytest
from ruckig import Synchronization

from kinesphere import zconfig
from kinesphere.protocol import (
    Ack,
    Catalogue,
    Command,
    Drive,
    RobotState,
    SpatialCommand,
    decode,
    encode,
)
from kinesphere.robots.agent import fleet as fleet_module
from kinesphere.robots.agent.bodies import make_body
from kinesphere.robots.agent.fleet import FleetHost, RobotSpec, state_steps
from kinesphere.robots.agent.follow import Followers
from kinesphere.robots.agent.mujoco_body import HardStops, MujocoBody
from kinesphere.robots.agent.otg import Otg
from kinesphere.robots.agent.pacing import STALL_NS
from kinesphere.robots.agent.resolver import parts_key
from kinesphere.robots.agent.runtime import Agent, AgentOptions
from support.agents import DatabankProcess, far
from support.network import KEYS, Hub
from support.wait import WAIT_S, until

DT = 0.002


def generators(seed: int) -> list[Otg]:
    """Generators of 2 to 26 DoF with their own limits, starts and position bounds."""
    rng = np.random.default_rng(seed)
    out = []
    for n in (2, 5, 9, 14, 26, 3):
        out.append(Otg(n, DT, rng.uniform(0.5, 2, n), rng.uniform(1, 8, n),
                       rng.uniform(10, 80, n), rng.uniform(-1, 1, n), [-3.0] * n, [3.0] * n))
        rng = np.random.default_rng(seed + n)
    return out


def test_followers_give_ruckigs_own_outputs_bit_for_bit() -> None:
    """Targets (some with a minimum duration), brakes, velocity targets and limit changes at
    random, mid-motion too: every output of every step is the one Ruckig's ``update`` gives
    (a generator of its own), and so is the time the motion has left."""
    logging.getLogger("kinesphere.robots.agent.otg").setLevel(logging.ERROR)  # refused plans
    rng = np.random.default_rng(7)
    alone, followed = generators(3), generators(3)
    followers = Followers(followed, DT)
    seen = {"followed": 0, "brake": 0, "ended": 0, "timed": 0}
    for step in range(6000):
        for a, b in zip(alone, followed, strict=True):
            roll = rng.random()
            if roll < 0.004:
                target = rng.uniform(-2.5, 2.5, a.n)
                sync = (Synchronization.Time, Synchronization.Phase,
                        Synchronization.No)[rng.integers(3)]
                duration = float(rng.uniform(0.5, 4.0)) if rng.random() < 0.5 else None
                seen["timed"] += duration is not None
                a.go_to(target, sync, duration)
                b.go_to(target, sync, duration)
            elif roll < 0.006:
                a.brake()
                b.brake()
                seen["brake"] += 1
            elif roll < 0.007:
                v = rng.uniform(-0.5, 0.5, a.n)
                a.go_at(v)
                b.go_at(v)
            elif roll < 0.008:
                share = rng.uniform(0, 1, a.n)
                a.scale(share)
                b.scale(share)
        was = [b.following for b in followed]
        followers.advance()
        for a, b, followed_here in zip(alone, followed, was, strict=True):
            assert a.step() == b.step()
            seen["followed"] += followed_here
            seen["ended"] += followed_here and not b.active
            for name in ("position", "velocity", "acceleration", "target"):
                assert np.array_equal(getattr(a, name), getattr(b, name)), (step, name)
            assert (a.active, a.fault) == (b.active, b.fault), step
            assert abs(a.remaining - b.remaining) < 1e-9, (step, a.remaining, b.remaining)
    assert seen["followed"] > 20_000 and seen["brake"] > 50 and seen["ended"] >= 10, seen
    assert seen["timed"] > 20, seen


def test_hard_stops_put_back_only_the_joints_past_a_limit() -> None:
    bodies = [make_body("mujoco", p, DT) for p in ("nao", "baxter", "youbot", "nao")]
    mbodies = [b for b in bodies if isinstance(b, MujocoBody)]
    stops = HardStops(mbodies)
    nao, baxter, youbot, other = mbodies
    for b in mbodies:
        mujoco.mj_step(b.model, b.data)
    before = [(b.data.qpos.copy(), b.data.qvel.copy()) for b in mbodies]
    stops.apply()  # nothing is past a limit: nothing changes
    assert all(np.array_equal(b.data.qpos, q) and np.array_equal(b.data.qvel, v)
               for b, (q, v) in zip(mbodies, before, strict=True))
    j = len(nao._qadr) - 1  # NAO's joints are not contiguous in qpos: its last joint
    nao.data.qpos[nao._qadr[j]] = nao._upper[j] + 0.02
    nao.data.qvel[nao._dadr[j]] = 1.0
    youbot.data.qpos[youbot._qadr[0]] = youbot._lower[0] - 0.03
    youbot.data.qvel[youbot._dadr[0]] = -2.0
    stops.apply()
    assert nao.data.qpos[nao._qadr[j]] == nao._upper[j] and nao.data.qvel[nao._dadr[j]] == 0.0
    assert youbot.data.qpos[youbot._qadr[0]] == youbot._lower[0]
    assert youbot.data.qvel[youbot._dadr[0]] == 0.0
    for b, (q, v) in ((baxter, before[1]), (other, before[3])):
        assert np.array_equal(b.data.qpos, q) and np.array_equal(b.data.qvel, v)
    # the per-body stop, on a copy, agrees
    single = make_body("mujoco", "nao", DT)
    assert isinstance(single, MujocoBody)
    mujoco.mj_copyData(single.data, single.model, nao.data)
    single.data.qpos[single._qadr[j]] = single._upper[j] + 0.02
    single.stop_at_limits()
    assert np.array_equal(single.data.qpos, nao.data.qpos)


PLATFORMS = ("baxter", "youbot", "nao", "khepera")


def moves(cat: Catalogue) -> list[tuple[str, str, str, float]]:
    """Two far reaches of the first limb, or two base translations for a body without one;
    then the second reach past the largest size (a translation too, on a mobile base)."""
    if not cat.limbs:
        c = cat.core[0]
        return [(c, c, "forward-middle", 2.0), (c, c, "left-middle", 2.0),
                (c, c, "back-middle", 3.0)]
    first, second = far(cat, 0), far(cat, 1)
    entry = cat.limbs[0]
    ahead = next(d for d in entry.directions if not d.startswith("place"))  # not vertical
    mobile = cat.base_kind not in ("fixed", "")
    return [first, second, (entry.limb, entry.origin, ahead,
                            max(entry.sizes) + (2.0 if mobile else 0.0))]


def named(status: tuple[str, str], robot_id: str) -> tuple[str, str]:
    """A robot's status and detail with its own id as ``ID``: twins compare equal."""
    return status[0], status[1].replace(robot_id, "ID")


def payload(seq: int, parts: list[tuple[str, str, str, float]] | None = None,
            **kw: object) -> bytes:
    fields: dict[str, object] = {"seq": seq, "sent_ns": time.time_ns(), "deadman": True,
                                 "ttl_ms": 0, "sender": "test"}
    fields.update(kw)
    return encode(Command(parts=[SpatialCommand(*p) for p in parts or []], **fields))  # type: ignore[arg-type]


def test_a_fleet_robot_steps_exactly_like_a_lone_agent(
    hub: Hub, databank: DatabankProcess
) -> None:
    """The same commands at the same steps to robots of a fleet host (lean steps, glides with
    and without a moving base, robot time kept for all at once, followers, batched stops) and
    to lone agents (their whole cycle every step) from the same state: the same bodies,
    statuses and acks, step by step, and every joint within its limits at every step."""
    _session, endpoint = hub
    poses = {p: moves(databank.catalogue(p)) for p in PLATFORMS}
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        fleet = FleetHost([RobotSpec(p, f"lean-f-{p}") for p in PLATFORMS], s,
                      AgentOptions(speed=0.0), helpers=0)
        lone = [Agent(p, f"lean-a-{p}", s, AgentOptions(speed=0.0)) for p in PLATFORMS]
        pairs = list(zip(fleet.agents, lone, strict=True))
        said: dict[str, list[tuple[int, str, str]]] = {}
        try:
            fleet.declare()
            for a in lone:
                a.declare()
            for f, a in pairs:  # what each says, in order: (seq, stage, code)
                for agent in (f, a):
                    log = said.setdefault(agent.robot_id, [])
                    agent.conduct.acks.publish = agent.conduct.acks.publish_urgent = (
                        lambda data, log=log: log.append(_stage(data)))
            for k in (0, 1, 2):  # every pose resolved and cached on both sides
                for f, a in pairs:
                    for agent in (f, a):
                        agent.receive(payload(k + 1, [poses[agent.platform][k]]))
                deadline = time.monotonic() + 30
                while not all(x.resolver.cached(parts_key([SpatialCommand(*poses[x.platform][k])]))
                              for pair in pairs for x in pair):
                    fleet.tick()
                    for a in lone:
                        a.tick()
                    assert time.monotonic() < deadline, "poses not resolved"
            for f, a in pairs:  # both stop and rest, then start from the same state
                for agent in (f, a):
                    agent.receive(payload(10, stop=True))
            for _ in range(150):
                fleet.tick()
                for a in lone:
                    a.tick()
            fleet.complete()
            for f, a in pairs:
                fb, ab = f.controller.body, a.controller.body
                assert isinstance(fb, MujocoBody) and isinstance(ab, MujocoBody)
                mujoco.mj_copyData(ab.data, ab.model, fb.data)
                for agent in (f, a):
                    agent.controller.fail_safe()
                    agent.conduct.acks.motion = None
                    said[agent.robot_id].clear()
            script = {
                0: lambda p: payload(20, [poses[p][0]]),
                150: lambda p: payload(21, [poses[p][1]]),  # mid-motion
                400: lambda p: payload(22, stop=True),
                450: lambda p: payload(23, [poses[p][0]]),
                1600: lambda p: payload(24, [poses[p][0]]),  # the same target again
                1700: lambda p: (payload(25, drive=Drive(forward=0.4, yaw=0.3), ttl_ms=60_000)
                                 if p in ("youbot", "khepera") else payload(25, [poses[p][1]])),
                1900: lambda p: payload(26, [poses[p][2]]),  # past the largest size
                2600: lambda p: payload(27, estop=True),
                2650: lambda p: payload(28, release=True),
                2700: lambda p: payload(29, [poses[p][1]]),
            }
            followed: dict[str, int] = {}  # steps the followers took, per robot and generator
            kinds: dict[str, int] = {}  # steps of each kind the fleet's robots took
            for step in range(3600):
                for i, f in enumerate(fleet.agents):
                    kind = f"{f.platform} {fleet.step_kind(i)}"
                    kinds[kind] = kinds.get(kind, 0) + 1
                    if fleet.ledgered(i):
                        kinds[f"{f.platform} ledgered"] = kinds.get(f"{f.platform} ledgered", 0) + 1
                for f in fleet.agents:
                    for name, gen in zip(("joints", "base"), f.controller.generators,
                                         strict=False):
                        followed[f"{f.platform} {name}"] = (followed.get(f"{f.platform} {name}", 0)
                                                            + gen.following)
                if step in script:
                    for f, a in pairs:
                        f.receive(script[step](f.platform))
                        a.receive(script[step](a.platform))
                fleet.tick()
                fleet.complete()  # this step's end now, as a lone agent's tick has it
                for f, a in pairs:
                    a.tick()
                    fd, ad = f.controller.body.data, a.controller.body.data  # type: ignore[attr-defined]
                    assert np.array_equal(fd.qpos, ad.qpos), (f.platform, step)
                    assert np.array_equal(fd.qvel, ad.qvel), (f.platform, step)
                    assert named(f.status(), f.robot_id) == named(a.status(), a.robot_id), \
                        (f.platform, step)  # a detail may name the robot (a release's --target)
                    assert said[f.robot_id] == said[a.robot_id], (f.platform, step)
                    for name, q in zip(f.controller.joint_names, f.controller.q(), strict=True):
                        lim = f.controller.platform.eurdf.limits[name]
                        assert lim.lower <= q <= lim.upper, (f.robot_id, name, q, step)
                # every way checked before the next step on both sides alike: unpaced, a check
                # late by the guard's UNCHECKED_S of robot time would brake one side only
                for agent in (*fleet.agents, *lone):
                    guard = agent.controller.guard
                    if guard is not None:
                        assert guard.settle(WAIT_S), agent.robot_id
            followed.pop("khepera joints")  # no limb: its joints never move
            assert min(followed.values()) > 200, followed  # the bases' steps too
            for p in ("baxter", "nao", "youbot"):  # the fleet handed their setpoints over itself
                assert kinds.get(f"{p} glide", 0) > 200, kinds
            assert kinds.get("khepera glide", 0) > 200, kinds  # its base's steps: rolling
            for p in PLATFORMS:  # their robot time and motion noted for all at once
                assert kinds.get(f"{p} ledgered", 0) > 200, kinds
            for p in PLATFORMS:
                stages = {stage for _, stage, _ in said[f"lean-f-{p}"]}
                assert {"accepted", "moving", "reached", "superseded", "stopped", "estopped",
                        "released"} <= stages, (p, stages)
        finally:
            fleet.close()
            for a in lone:
                a.close()


def test_a_robot_at_rest_beside_gliding_ones_of_its_platform_stays_exactly_at_rest(
    hub: Hub, databank: DatabankProcess
) -> None:
    """Robots of one platform on one fleet host, one moving, one at rest: the one at rest
    steps exactly as a lone agent of its platform that got no command (its setpoints are
    nobody else's), the moving one glides (the fleet hands its followed setpoints over), and
    every joint of every robot stays within its limits at every step."""
    _session, endpoint = hub
    platforms = ("baxter", "nao")
    poses = {p: moves(databank.catalogue(p)) for p in platforms}
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        specs = [RobotSpec(p, f"rest-{role}-{p}") for p in platforms for role in ("go", "still")]
        fleet = FleetHost(specs, s, AgentOptions(speed=0.0), helpers=0)
        lone = {p: Agent(p, f"rest-lone-{p}", s, AgentOptions(speed=0.0)) for p in platforms}
        try:
            fleet.declare()
            for a in lone.values():
                a.declare()
            movers = [a for a in fleet.agents if "-go-" in a.robot_id]
            still = {a.platform: a for a in fleet.agents if "-still-" in a.robot_id}
            for _ in range(50):  # everyone settles on their own, side by side
                fleet.tick()
                for a in lone.values():
                    a.tick()
            fleet.complete()
            for p, a in still.items():  # the resting pair from the same state on
                fb, ab = a.controller.body, lone[p].controller.body
                assert isinstance(fb, MujocoBody) and isinstance(ab, MujocoBody)
                mujoco.mj_copyData(ab.data, ab.model, fb.data)
            ctrl = {p: a.controller.body.data.ctrl.copy() for p, a in still.items()}  # type: ignore[attr-defined]
            for k, a in enumerate(movers):
                a.receive(payload(1, [poses[a.platform][k % 2]]))
            glided = 0
            deadline = time.monotonic() + WAIT_S
            while not all(a.status()[1] == "at target" for a in movers):
                assert time.monotonic() < deadline, [a.status() for a in movers]
                fleet.tick()
                fleet.complete()
                for a in lone.values():
                    a.tick()
                glided += sum(fleet.step_kind(i) == "glide" for i in range(len(fleet.agents)))
                for p, a in still.items():
                    fd, ld = a.controller.body.data, lone[p].controller.body.data  # type: ignore[attr-defined]
                    assert np.array_equal(fd.qpos, ld.qpos), p
                    assert np.array_equal(fd.ctrl, ctrl[p]), p
                for a in fleet.agents:
                    for name, q in zip(a.controller.joint_names, a.controller.q(), strict=True):
                        lim = a.controller.platform.eurdf.limits[name]
                        assert lim.lower <= q <= lim.upper, (a.robot_id, name, q)
            assert glided > 300, glided  # steps the movers glided, one per robot and step
        finally:
            fleet.close()
            for a in lone.values():
                a.close()


def test_a_resting_fleet_robot_sees_no_stall_but_a_stalled_loop_ages_new_clocks(
    hub: Hub
) -> None:
    """A robot at rest on a fleet host runs no cycle of its own for a long while: the loop
    still stepped, so a command from a clock never heard is fresh. When the loop itself did
    not step (frozen, a step hung), such a command that arrived meanwhile is as old as the
    stall (``ordering.py``, rule 3) and expires like on a lone agent."""
    _session, endpoint = hub
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        fleet = FleetHost([RobotSpec("khepera", "stall-f-khepera")], s, AgentOptions(speed=0.0),
                          helpers=0)
        agent = fleet.agents[0]
        said: list[tuple[int, str, str]] = []
        try:
            fleet.declare()
            agent.conduct.acks.publish = agent.conduct.acks.publish_urgent = (
                lambda data: said.append(_stage(data)))
            begun = time.monotonic()
            while time.monotonic() - begun < 3 * STALL_NS / 1e9:  # the loop steps, the robot rests
                fleet.tick()
            assert not agent.needs_cycle() and agent.at_rest
            agent.receive(payload(1, drive=Drive(forward=0.2), ttl_ms=300, sender="op-a"))
            for _ in range(3):
                fleet.tick()
            fleet.complete()
            assert (1, "accepted", "") in said, said
            before = len(said)
            time.sleep(5 * STALL_NS / 1e9)  # the stall itself, not a wait for anything
            agent.receive(payload(1, drive=Drive(forward=0.2), ttl_ms=300, sender="op-b"))
            for _ in range(3):
                fleet.tick()
            fleet.complete()
            assert (1, "rejected", "expired") in said[before:], said  # op-b's
            assert (1, "accepted", "") not in said[before:], said
        finally:
            fleet.close()


def _stage(data: bytes) -> tuple[int, str, str]:
    ack = decode(data, Ack)
    return ack.seq, str(ack.stage), ack.code


def test_state_steps_group_the_robots_and_spread_the_groups() -> None:
    """Each robot publishes in one step of the period; robots share a step in groups of at
    most the burst (more only when the period has too few steps), the groups in different
    steps, spread over the period."""
    for robots, every, burst in ((1, 10, 16), (16, 10, 16), (17, 10, 16), (32, 10, 8),
                                 (48, 10, 16), (5, 10, 2), (1024, 10, 16), (7, 1, 16)):
        steps = state_steps(robots, every, burst)
        assert len(steps) == robots and all(0 <= s < every for s in steps)
        groups = sorted(set(steps))
        sizes = [steps.count(s) for s in groups]
        assert len(groups) == min(every, -(-robots // burst)), (robots, every, burst, steps)
        assert max(sizes) <= max(burst, -(-robots // every)), (robots, every, burst, steps)
        assert max(sizes) - min(sizes) <= 1, (robots, every, burst, steps)
        gaps = np.diff([*groups, groups[0] + every])
        assert gaps.max() - gaps.min() <= 1, (robots, every, burst, steps)


def test_a_fleet_puts_the_states_of_a_group_after_composing_them_all(
    hub: Hub, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Five robots, groups of two: every robot's state once per period, in the step
    ``state_steps`` gives it; in each step every state due is composed before the first is
    put (so Zenoh sends them as one batch), and a subscriber hears each one."""
    session, endpoint = hub
    monkeypatch.setattr(fleet_module, "STATE_BURST", 2)
    heard: list[tuple[str, int]] = []
    sub = session.declare_subscriber(
        KEYS.state("*"), lambda s: heard.append((decode(s.payload, RobotState).robot_id,
                                                 decode(s.payload, RobotState).seq)))
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        specs = [RobotSpec("khepera", f"burst-{i}") for i in range(5)]
        fleet = FleetHost(specs, s, AgentOptions(speed=0.0), helpers=0)
        every = fleet.agents[0].publish_every
        calls: list[tuple[str, str]] = []

        def spied(name: str, robot_id: str, real: Callable[[], object]) -> Callable[[], object]:
            def spy() -> object:
                calls.append((name, robot_id))
                return real()
            return spy

        for a in fleet.agents:
            for name in ("compose_state", "put_state"):
                monkeypatch.setattr(a, name, spied(name, a.robot_id, getattr(a, name)))
        try:
            fleet.declare()
            expected = state_steps(5, every, 2)
            assert expected == [0, 0, 3, 3, 6]
            for pub in [a._publisher for a in fleet.agents]:
                assert zconfig.wait_matching(pub)
            heard.clear()
            periods = 3
            for step in range(periods * every):
                calls.clear()
                fleet.tick()
                fleet.complete()  # the step's end: its states
                due = [a.robot_id for a, k in zip(fleet.agents, expected, strict=True)
                       if k == fleet.stats.begun % every]
                assert calls == [("compose_state", r) for r in due] + \
                    [("put_state", r) for r in due], (step, calls)
            until(lambda: len(heard) >= periods * 5, WAIT_S, "every state heard")
            assert sorted(heard) == sorted((a.robot_id, seq) for a in fleet.agents
                                           for seq in range(1, periods + 1)), heard
        finally:
            fleet.close()
            zconfig.undeclare(sub)
