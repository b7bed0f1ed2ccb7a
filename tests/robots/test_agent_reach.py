"""Commands reach ECL poses: every platform, jerk-limited, continuous through retargets, and a
wildcard command moving three different robots at once, each to its own platform's pose."""

from __future__ import annotations

import math
from collections.abc import Callable
from contextlib import ExitStack

import numpy as np
import pytest

from kinesphere.protocol import Pose, RobotState, SpatialCommand
from kinesphere.robots.agent.runtime import Agent
from support.agents import (
    CommandSender,
    DatabankProcess,
    Trace,
    far,
    finite_jerk,
    joints_close,
    knows,
    real_pulls,
    running_agent,
)
from support.network import Hub

PLATFORMS = ["baxter", "nao", "youbot", "packbot", "khepera"]
TOL = 5e-3
"""rad (m): how close the simulated joints come to the (clamped) target once at rest."""


def reached(agent: Agent, pose: Pose) -> Callable[[RobotState], bool]:
    """Predicate: at rest at the pose (as clamped by the agent's limit margin)."""
    target, _ = agent.controller.joints.clamp(pose.joints)
    goal = (pose.translation or [0.0, 0.0])[:2]

    def pred(s: RobotState) -> bool:
        return (s.status in ("idle", "clamped") and joints_close(s, target, TOL)
                and math.dist(s.base_pose[:2], goal) <= TOL)

    return pred


def check_limits(trace: Trace, agent: Agent) -> None:
    """Ruckig's output respects jerk, acceleration, velocity (finite differences, not sim)."""
    p = agent.controller.platform
    jerk, dv = finite_jerk(trace)
    assert jerk.max() <= p.max_jerk * (1 + 1e-6)
    assert dv.max() <= p.max_acceleration * agent.controller.dt * (1 + 1e-6)
    vel = np.abs(np.array(trace.vel))
    assert (vel <= agent.controller.joints.max_velocity * (1 + 1e-6)).all()


@pytest.mark.parametrize("platform", PLATFORMS)
def test_one_command_reaches_the_ecl_pose(
    hub: Hub, databank: DatabankProcess, platform: str
) -> None:
    session, endpoint = hub
    cat = databank.catalogue(platform)
    if cat.limbs:
        part = SpatialCommand(*far(cat, len(real_pulls(cat.limbs[0])) // 2))
    else:  # a limbless robot (khepera): its ECL is the core's translations
        part = SpatialCommand(cat.core[0], cat.core[0], cat.directions_for_core[0], 3.0)
    pose = databank.query(platform, part)
    trace = Trace()
    with (running_agent(endpoint, platform, speed=4.0, trace=trace) as (agent, watch),
          CommandSender(session, agent.robot_id) as op):
        seq = op.send(part)
        state = watch.after(seq, reached(agent, pose), f"{platform} at {pose}")
    assert state.platform == platform
    assert agent.resolver.queries == 1
    if pose.joints:
        moved = np.abs(np.array(trace.pos[-1]) - np.array(trace.pos[0])).max()
        assert moved > 0.05, "the pose should be a real motion"
    check_limits(trace, agent)


def test_retarget_mid_motion_stays_continuous(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    cat = databank.catalogue("baxter")
    first, second = far(cat, 0), far(cat, -1)
    trace = Trace()
    with (running_agent(endpoint, "baxter", speed=2.0, trace=trace) as (agent, watch),
          CommandSender(session, agent.robot_id) as op):
        seq = op.send(first)
        watch.after(seq, lambda s: max(map(abs, s.qd)) > 0.3, "baxter under way")
        at_retarget = len(trace.t)
        seq = op.send(second)
        pose = databank.query("baxter", SpatialCommand(*second))
        watch.after(seq, reached(agent, pose), "baxter at the second pose")
    vel = np.array(trace.vel)
    assert np.abs(vel[at_retarget]).max() > 0.1, "the retarget happened mid-motion"
    check_limits(trace, agent)  # includes: no velocity jump at the retarget


def test_wildcard_command_moves_every_robot_to_its_own_pose(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    robots = ["baxter", "nao", "youbot"]
    cats = {r: databank.catalogue(r) for r in robots}
    shared = set.intersection(*(
        {(e.limb, e.origin, d) for e in c.limbs for d in real_pulls(e)}
        for c in cats.values()
    ))
    assert shared, "no spatial command is valid on all three platforms"
    limb, origin, direction = sorted(shared)[0]
    part = SpatialCommand(limb, origin, direction, 2.0)
    poses = {r: databank.query(r, part) for r in robots}
    with ExitStack() as stack:
        running = {r: stack.enter_context(running_agent(endpoint, r, speed=2.0)) for r in robots}
        op = stack.enter_context(CommandSender(session, "*"))
        for r in robots:
            knows(session, r)
        seq = op.send(part)
        for r, (agent, watch) in running.items():
            watch.after(seq, reached(agent, poses[r]), f"{r} at its own pose")
    names = {r: set(p.joints) for r, p in poses.items()}
    assert not names["baxter"] & names["nao"], "different bodies, different joints"
