"""The Body seam: the agent drives any body, and a failing plan or body never stops its loop.

A kinematic body (joints are where they were commanded, the base integrates its commanded
velocity; no MuJoCo anywhere) runs the real agent over real Zenoh against the real databank;
a body that fails, and a target Ruckig cannot plan, show that the loop goes on stepping and
publishing with ``error`` and a reason.
"""

from __future__ import annotations

import math
import queue
import time
from collections.abc import Sequence

import numpy as np
import pytest

from kinesphere import zconfig
from kinesphere.errors import KinesphereError
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import Drive, SpatialCommand, encode
from kinesphere.robots.agent.base import rotate
from kinesphere.robots.agent.bodies import BODIES, make_body
from kinesphere.robots.agent.body import Body, Reading
from kinesphere.robots.agent.options import BODY_KINDS
from kinesphere.robots.agent.runtime import Agent, AgentOptions
from support.agents import (
    CommandSender,
    DatabankProcess,
    StateWatch,
    far,
    joints_close,
    running_agent,
)
from support.network import Hub


class KinematicBody(Body):
    """A perfect body: joints at their commanded positions, base at its integrated velocity.

    It records every command, so a test sees exactly what crossed the seam.
    """

    def __init__(self, platform: str, dt: float) -> None:
        self.platform = load_platform(platform)
        self.dt = dt
        self.q = self.platform.neutral_vector()
        self.qd = np.zeros_like(self.q)
        self.pose = np.zeros(3)
        self.commands: list[np.ndarray] = []
        self.halts = 0

    def read(self) -> Reading:
        return Reading(self.q.copy(), self.qd.copy(),
                       (float(self.pose[0]), float(self.pose[1]), float(self.pose[2])))

    def command(self, q: np.ndarray, base_twist: Sequence[float] | np.ndarray) -> None:
        self.qd = (q - self.q) / self.dt
        self.q = np.array(q, dtype=float)
        vx, vy, w = base_twist
        dx, dy = rotate(vx * self.dt, vy * self.dt, float(self.pose[2]) + 0.5 * w * self.dt)
        self.pose += (dx, dy, w * self.dt)
        self.commands.append(self.q.copy())

    def step(self) -> None:
        pass

    def halt(self) -> None:
        self.halts += 1
        self.qd[:] = 0.0


class DriverLostBody(KinematicBody):
    """Fails every step from step ``after`` on, like a body whose driver died."""

    def __init__(self, platform: str, dt: float, after: int) -> None:
        super().__init__(platform, dt)
        self.after = after
        self.steps = 0

    def step(self) -> None:
        self.steps += 1
        if self.steps > self.after:
            raise RuntimeError("driver lost")


class StallingBody(KinematicBody):
    """Its driver stalls once, for ``stall_s`` of wall time, at step ``stall_at`` (set by the
    test): robot time stands still meanwhile, as it does for a frozen or starved process."""

    def __init__(self, platform: str, dt: float, stall_s: float) -> None:
        super().__init__(platform, dt)
        self.stall_s = stall_s
        self.stall_at = -1
        self.steps = 0

    def step(self) -> None:
        self.steps += 1
        if self.steps == self.stall_at:
            time.sleep(self.stall_s)  # the stall itself, not a wait for anything


def test_the_watchdog_runs_on_the_wall_clock_through_a_stalled_step(
    hub: Hub,
) -> None:
    """A drive with a 300 ms TTL, then the body stalls 1 s in one step: the first step after
    the stall holds (robot time alone would have driven on for most of the TTL)."""
    session, endpoint = hub
    body = StallingBody("youbot", 1.0 / 500.0, stall_s=1.0)
    seen: list[tuple[int, str]] = []
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        agent = Agent("youbot", "stalling", s, AgentOptions(speed=1.0), body=body)
        agent.controller.on_step = lambda c: seen.append((body.steps, agent.status()[0]))
        watch = StateWatch(s, "stalling")
        agent.start()
        try:
            with CommandSender(session, agent.robot_id, sender="ann", client_session="a") as op:
                seq = op.send(drive=Drive(forward=0.5), ttl_ms=300)
                watch.after(seq, lambda st: st.base_pose[0] > 0.001, "driving")
                body.stall_at = body.steps + 2
                held = watch.after(seq, lambda st: st.status == "holding",
                                   "held by the watchdog")
        finally:
            agent.close()
            watch.close()
    assert "ttl" in held.detail
    after = [status for step, status in seen if step >= body.stall_at]
    assert "holding" in after[:3], f"held {after.index('holding')} steps after the stall"


def test_an_agent_drives_a_kinematic_body_over_the_wire(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    cat = databank.catalogue("youbot")
    reach, beyond = far(cat, horizontal=True), far(cat, horizontal=True, past=2.0)
    pose = databank.query("youbot", SpatialCommand(*reach))
    translated = databank.query("youbot", SpatialCommand(*beyond))
    assert translated.translation is not None
    body = KinematicBody("youbot", 1.0 / 500.0)
    with (running_agent(endpoint, "youbot", "kinematic", own_body=body) as (agent, watch),
          CommandSender(session, agent.robot_id) as op):
        target, _ = agent.controller.joints.clamp(pose.joints)
        seq = op.send(reach)
        watch.after(seq, lambda st: st.status == "idle" and joints_close(st, target, 1e-9),
                    "the kinematic body exactly at the pose")
        seq = op.send(beyond)
        goal = translated.translation
        done = watch.after(seq, lambda st: st.status == "idle" and math.dist(
            st.base_pose[:2], goal[:2]) < 1e-6, "the base translated")
        seq = op.send(estop=True)
        watch.after(seq, lambda st: st.status == "estop", "e-stop obeyed")
    assert done.robot_id == "kinematic" and done.platform == "youbot"
    q = np.array(body.commands)
    dv = np.abs(np.diff(q, n=2, axis=0)).max() / agent.controller.dt**2
    assert dv <= load_platform("youbot").max_acceleration * (1 + 1e-6), \
        "the body was sent Ruckig's jerk-limited positions"


def test_a_body_that_fails_never_stops_the_state_stream(hub: Hub) -> None:
    _, endpoint = hub
    body = DriverLostBody("baxter", 1.0 / 500.0, after=50)
    with running_agent(endpoint, "baxter", "failing", own_body=body) as (_, watch):
        first = watch.wait(lambda st: st.status == "error", "the failure reported")
        later = watch.wait(lambda st: st.seq >= first.seq + 20, "states keep coming")
    assert "control step failed" in first.detail and "driver lost" in first.detail
    assert later.status == "error" and body.halts > 0


def test_the_agent_reports_an_unplannable_target_and_keeps_publishing(
    hub: Hub,
) -> None:
    _, endpoint = hub
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        agent = Agent("youbot", "unplannable", s, AgentOptions(speed=0.0))
        watch = StateWatch(s, "unplannable")
        agent.declare()
        try:
            assert agent.controller.base is not None
            agent.controller.base.translate([2.5e9, 0.0, 0.0])
            agent.conduct.set("moving", "test")
            for _ in range(1000):
                agent.tick()
            state = watch.wait(lambda st: st.seq >= 10 and st.status == "error",
                               "error published")
        finally:
            agent.close()
            watch.close()
    assert "ruckig cannot plan" in state.detail and "holding" in state.detail
    assert not agent.controller.moving and abs(state.base_pose[0]) < 1e-3


def test_the_published_bytes_are_those_of_the_state_the_agent_built(hub: Hub) -> None:
    """States are encoded into one buffer the agent keeps: each put carries exactly the
    encoding of its own state, a short one after a long one included."""
    _, endpoint = hub
    heard: queue.Queue[bytes] = queue.Queue()
    with zconfig.session(config=zconfig.loopback_config(endpoint)) as s:
        agent = Agent("baxter", "encoded", s, AgentOptions(speed=0.0))
        sub = s.declare_subscriber(agent.keys.state("encoded"),
                                   lambda sample: heard.put(bytes(sample.payload)))
        agent.declare()
        try:
            built = []
            for detail in ("x" * 900, "short", "", "y" * 300):
                agent.conduct.set("holding", detail)
                built.append(agent.publish())
            got = [heard.get(timeout=10.0) for _ in built]  # the loop runs in no thread here
        finally:
            agent.close()
            zconfig.undeclare(sub)
    assert [st.detail for st in built] == ["x" * 900, "short", "", "y" * 300]
    assert got == [encode(st) for st in built]


def test_unknown_bodies_are_named() -> None:
    with pytest.raises(KinesphereError) as err:
        make_body("hydraulic", "youbot", 0.002)
    assert err.value.code == "malformed" and "mujoco" in err.value.message
    with pytest.raises(KinesphereError):
        AgentOptions(body="hydraulic")
    assert list(BODIES) == list(BODY_KINDS)  # every name the options accept has a factory
