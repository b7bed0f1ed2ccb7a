"""A command's ``arrive_ms``: the robot plans its motion to arrive then (Ruckig's minimum
duration), or as soon after as its limits allow and says how late (``Ack.late_ms``); and a
command's ``heading`` turns a mobile base, while a fixed base refuses it.

In robot time, without the network: an in-process agent is ticked by hand and its acks are
read where it publishes them, so every figure is exact to a control step.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import msgspec
import numpy as np
import pytest

from kinesphere import zconfig
from kinesphere.errors import KinesphereError
from kinesphere.eurdf import JointLimit
from kinesphere.protocol import Ack, Command, decode, encode
from kinesphere.robots.agent.runtime import Agent
from kinesphere.robots.agent.trajectory import JointTrajectory

DT = 0.002
LIMITS = [JointLimit("a", "revolute", -2.0, 2.0, 1.5), JointLimit("b", "revolute", -2.0, 2.0, 3.0)]


def steps_to_rest(traj: JointTrajectory) -> int:
    n = 0
    while traj.moving:
        traj.step()
        n += 1
    return n


def test_a_trajectory_with_time_to_spare_arrives_when_asked_and_says_so() -> None:
    traj = JointTrajectory(LIMITS, 4.0, 40.0, DT, [0.0, 0.0])
    traj.retarget({"a": 0.5, "b": -0.3}, duration=2.0)
    traj.step()
    assert traj.remaining == pytest.approx(2.0 - DT, abs=1e-9)
    n = 1 + steps_to_rest(traj)
    assert n * DT == pytest.approx(2.0, abs=DT)
    np.testing.assert_allclose(traj.position, [0.5, -0.3], atol=1e-9)


def test_a_trajectory_without_the_time_arrives_as_soon_as_its_limits_allow() -> None:
    quick = JointTrajectory(LIMITS, 4.0, 40.0, DT, [0.0, 0.0])
    quick.retarget({"a": 1.8, "b": -1.8})
    fastest = steps_to_rest(quick) * DT
    asked = JointTrajectory(LIMITS, 4.0, 40.0, DT, [0.0, 0.0])
    asked.retarget({"a": 1.8, "b": -1.8}, duration=fastest / 3)
    asked.step()
    assert asked.remaining + DT == pytest.approx(fastest, abs=DT)  # planned: this late
    assert (1 + steps_to_rest(asked)) * DT == pytest.approx(fastest, abs=DT)


def _agent(platform: str) -> Iterator[tuple[Agent, list[Ack]]]:
    alone = zconfig.session_config(listen=[zconfig.LOOPBACK_ANY_PORT], connect=[])
    with zconfig.session(alone) as s:
        agent = Agent(platform, f"timing-{platform}", s)
        said: list[Ack] = []
        agent.conduct.acks.publish = lambda b: said.append(decode(b, Ack))
        start = time.monotonic()  # the host's clock keeps the robot's pace: no loop falls behind
        agent.conduct.wall = lambda: start + agent.controller.time
        try:
            yield agent, said
        finally:
            agent.close()


@pytest.fixture
def youbot() -> Iterator[tuple[Agent, list[Ack]]]:
    yield from _agent("youbot")


@pytest.fixture
def baxter() -> Iterator[tuple[Agent, list[Ack]]]:
    yield from _agent("baxter")


def command(seq: int, heading: float | None, arrive_ms: int) -> bytes:
    return encode(Command(seq=seq, sent_ns=time.time_ns(), deadman=True, ttl_ms=0,
                          sender="conductor", session="s", heading=heading,
                          arrive_ms=arrive_ms))


def stages(said: list[Ack], seq: int) -> dict[str, Ack]:
    return {a.stage: a for a in said if a.seq == seq}


def test_a_mobile_base_turns_to_a_heading_by_the_time_it_is_given(
        youbot: tuple[Agent, list[Ack]]) -> None:
    agent, said = youbot
    ctrl = agent.controller
    agent.receive(command(1, math.radians(30), 3000))
    start = ctrl.time
    agent.tick()
    while ctrl.moving:
        agent.tick()
    took = ctrl.time - start
    assert took == pytest.approx(3.0, abs=0.05)  # 3 s of robot time (ticks are unpaced)
    assert ctrl.base_pose()[2] == pytest.approx(math.radians(30), abs=2e-3)
    acks = stages(said, 1)
    assert {"accepted", "moving"} <= acks.keys() and acks["moving"].late_ms == 0

    agent.receive(command(2, math.radians(-150), 200))  # 180 degrees in 0.2 s: no base can
    agent.tick()
    late = stages(said, 2)["moving"]
    fastest = ctrl.remaining + ctrl.dt
    assert late.late_ms == pytest.approx(1e3 * (fastest + ctrl.dt - 0.2), abs=2 * 1e3 * ctrl.dt)
    assert f"arrives {late.late_ms} ms late" == late.detail
    while ctrl.moving:
        agent.tick()
    assert ctrl.base_pose()[2] == pytest.approx(math.radians(-150), abs=2e-3)
    for _ in range(200):  # settled: the final stage says how late it was, as it went
        agent.tick()
    final = stages(said, 2)["reached"]
    assert abs(final.late_ms - late.late_ms) <= 2 * 1e3 * ctrl.dt


def test_a_fixed_base_refuses_a_heading(baxter: tuple[Agent, list[Ack]]) -> None:
    agent, said = baxter
    agent.receive(command(1, 0.5, 1000))
    agent.tick()
    refused = stages(said, 1)["rejected"]
    assert refused.code == "cannot_translate" and "fixed base" in refused.detail


@pytest.mark.parametrize(("field", "value", "bound"), [
    ("arrive_ms", 60_001, "<= 60000"), ("arrive_ms", -1, ">= 0"),
    ("heading", math.nan, ">= -1000.0"), ("heading", 1e4, "<= 1000.0"),
])
def test_a_time_or_heading_out_of_bounds_is_malformed(field: str, value: float,
                                                      bound: str) -> None:
    raw = msgspec.to_builtins(Command(seq=1, sent_ns=1, deadman=True, ttl_ms=0))
    raw[field] = value
    with pytest.raises(KinesphereError) as err:
        decode(msgspec.msgpack.encode(raw), Command)
    assert err.value.code == "malformed" and bound in err.value.message
    assert f"$.{field}" in err.value.message


def test_a_motion_replaced_under_way_says_how_late_it_would_have_arrived(
        youbot: tuple[Agent, list[Ack]]) -> None:
    agent, said = youbot
    ctrl = agent.controller
    agent.receive(command(1, math.radians(180), 200))  # half a turn in 0.2 s: late
    agent.tick()
    planned = stages(said, 1)["moving"].late_ms
    assert planned > 200
    for _ in range(50):
        agent.tick()
    assert ctrl.moving
    agent.receive(command(2, 0.0, 1000))  # the next keyframe takes over before it arrived
    agent.tick()
    replaced = stages(said, 1)["superseded"]
    assert abs(replaced.late_ms - planned) <= 2 * 1e3 * ctrl.dt


def test_a_loop_behind_real_time_arrives_late_by_the_hosts_clock(
        youbot: tuple[Agent, list[Ack]]) -> None:
    agent, said = youbot
    ctrl = agent.controller
    agent.receive(command(1, math.radians(30), 3000))
    agent.tick()
    assert stages(said, 1)["moving"].late_ms == 0  # on time by the robot's plan
    host = agent.conduct.wall
    agent.conduct.wall = lambda: host() + 10.0  # the loop stalled 10 s of the host's time
    while ctrl.moving:
        agent.tick()
    for _ in range(200):
        agent.tick()
    late = stages(said, 1)["reached"].late_ms
    assert 9900 < late < 10100, late  # the robot's clock alone says on time


def test_the_next_keyframe_holding_the_pose_takes_over_and_the_one_before_says_it_was_late(
        youbot: tuple[Agent, list[Ack]]) -> None:
    """A score's keyframe that holds the pose of the one before (the same target, due later)
    is a new motion: a body that had not arrived by the first keyframe's time says so in the
    first one's acks, not in the next's (where a late first keyframe went unsaid)."""
    agent, said = youbot
    ctrl = agent.controller
    turn = math.radians(30)
    agent.receive(command(1, turn, 3000))
    while ctrl.time < 1.0:
        agent.tick()
    agent.receive(command(2, turn, round(1e3 * (3.0 - ctrl.time))))  # a copy: the same moment
    agent.tick()
    assert "superseded" not in stages(said, 1)
    host = agent.conduct.wall
    agent.conduct.wall = lambda: host() + 0.5  # the loop fell 0.5 s behind the host's clock
    while ctrl.time < 2.9:
        agent.tick()
    assert ctrl.moving
    agent.receive(command(3, turn, 3000))  # the next keyframe, the same pose 3 s later
    agent.tick()
    replaced = stages(said, 2)["superseded"]
    assert abs(replaced.late_ms - 500) <= 2 * 1e3 * ctrl.dt, replaced
    while ctrl.moving:
        agent.tick()
    for _ in range(200):
        agent.tick()
    assert ctrl.base_pose()[2] == pytest.approx(turn, abs=2e-3)
    assert stages(said, 3)["reached"].late_ms == 0
