"""Safety over the wire: deadman release, command TTL, e-stop latch and release, bad commands.

These run in real time (``speed=1``): the watchdog's timing against a client is the point.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack

import numpy as np
import pytest

from kinesphere.protocol import Command, RobotState, encode
from kinesphere.robots.agent.runtime import Agent
from kinesphere.robots.agent.safety import DRIVE_TTL_S
from support.agents import CommandSender, DatabankProcess, Trace, real_pulls, running_agent
from support.network import Hub


def status(*names: str) -> Callable[[RobotState], bool]:
    return lambda s: s.status in names


def base_speed(s: RobotState, prev: list[RobotState]) -> float:
    """Base speed between two states (m/s of robot time is close enough to wall time here)."""
    if not prev:
        prev.append(s)
        return 0.0
    a, prev[0] = prev[0], s
    dt = (s.stamp_ns - a.stamp_ns) / 1e9
    return float(np.hypot(s.base_pose[0] - a.base_pose[0], s.base_pose[1] - a.base_pose[1]) / dt)


def driving(min_speed: float) -> Callable[[RobotState], bool]:
    prev: list[RobotState] = []
    return lambda s: base_speed(s, prev) > min_speed


def halted(agent: Agent) -> Callable[[RobotState], bool]:
    return lambda s: s.status == "estop" and not agent.controller.moving


def check_braked(trace: Trace, max_acceleration: float, dt: float) -> None:
    """The base came to rest along a jerk-limited profile (no velocity jump)."""
    twist = np.array(trace.base_vel)
    assert np.abs(twist[-1]).max() == 0.0
    assert np.abs(np.diff(twist[:, :2], axis=0)).max() <= max_acceleration * dt * (1 + 1e-6)


@pytest.mark.parametrize(
    ("platform", "speed", "ttl_ms", "min_speed", "cause"),
    [("youbot", 1.0, 10_000, 0.05, "deadman"), ("packbot", 0.6, 300, 0.02, "ttl")],
    ids=["deadman-release", "ttl-expiry"],
)
def test_the_base_brakes_when_the_operator_lets_go(
    hub: Hub, platform: str, speed: float, ttl_ms: int, min_speed: float, cause: str,
) -> None:
    """Driving, the operator lets go: of the deadman button (still pushing the stick), or of
    everything (the client dies: no stop, no deadman release, just silence until the ttl
    runs out). The robot holds, says why, and the base brakes along a jerk-limited profile."""
    session, endpoint = hub
    trace = Trace()
    with running_agent(endpoint, platform, speed=1.0, trace=trace) as (agent, watch):
        with CommandSender(session, agent.robot_id) as op:  # then the client is gone
            seq = op.send(drive=("forward", speed), ttl_ms=ttl_ms)
            watch.after(seq, driving(min_speed), f"{platform} driving")
            if cause == "deadman":
                seq = op.send(drive=("forward", speed), deadman=False, ttl_ms=ttl_ms)
        held = watch.after(seq, status("holding"), f"holding after the {cause}")
        assert cause in held.detail
        watch.after(seq, lambda s: not agent.controller.moving, "base at rest")
    spec = agent.controller.platform.base
    check_braked(trace, spec.max_acceleration, agent.controller.dt)


def test_drive_without_ttl_still_needs_fresh_commands(hub: Hub) -> None:
    session, endpoint = hub
    with (running_agent(endpoint, "youbot", speed=4.0) as (agent, watch),
          CommandSender(session, agent.robot_id) as op):
        seq = op.send(drive=("left", 0.5), ttl_ms=0)
        watch.after(seq, status("holding"), "holding after the default drive watchdog")
    assert DRIVE_TTL_S > 0


def test_estop_halts_every_robot_latches_and_releases(
    hub: Hub, databank: DatabankProcess,
) -> None:
    session, endpoint = hub
    cat = databank.catalogue("baxter")
    entry = cat.limbs[0]
    pulls = real_pulls(entry)
    reach = (entry.limb, entry.origin, pulls[0], 3.0)
    with ExitStack() as stack:
        baxter, bw = stack.enter_context(running_agent(endpoint, "baxter", speed=1.0))
        youbot, yw = stack.enter_context(running_agent(endpoint, "youbot", speed=1.0))
        arm = stack.enter_context(CommandSender(session, "baxter", sender="arm"))
        base = stack.enter_context(CommandSender(session, "youbot", sender="base"))
        everyone = stack.enter_context(CommandSender(session, "*", sender="panic"))
        seq = arm.send(reach)
        bw.after(seq, lambda s: max(map(abs, s.qd)) > 0.2, "baxter moving")
        seq = base.send(drive=("forward", 1.0), ttl_ms=10_000)
        yw.after(seq, driving(0.05), "youbot driving")

        seq = everyone.send(estop=True)
        for agent, watch in ((baxter, bw), (youbot, yw)):
            watch.after(seq, halted(agent), f"{agent.robot_id} halted by the e-stop")

        # latched: ordinary commands are ignored, even with deadman held and a stop
        seq = base.send(drive=("forward", 1.0), ttl_ms=10_000, stop=True)
        yw.after(seq, status("estop"), "youbot still latched")
        assert not youbot.controller.moving

        # a streaming client (deadman held, no release flag) can never undo the e-stop
        seq = base.send(drive=("forward", 1.0), ttl_ms=10_000)
        yw.after(seq, status("estop"), "youbot still latched under a deadman stream")
        assert not youbot.controller.moving
        # a release from anyone but the e-stop's own sender clears nothing: the latch is panic's
        seq = base.send(drive=("forward", 1.0), ttl_ms=10_000, release=True)
        yw.after(seq, status("estop"), "youbot still latched: base cannot release panic's")
        # panic's release (to the youBot alone) clears its latch and moves nothing
        panic = stack.enter_context(CommandSender(session, "youbot", sender="panic"))
        seq = panic.send(drive=("forward", 1.0), ttl_ms=10_000, release=True, seq=seq + 1)
        yw.after(seq, status("idle"), "youbot released")
        assert not youbot.controller.moving
        seq = base.send(drive=("forward", 1.0), ttl_ms=10_000, seq=seq + 1)
        yw.after(seq, driving(0.05), "youbot drives again after the release")
        bw.wait(status("estop"), "baxter still latched (released separately)")


def test_bad_commands_are_reported_and_the_loop_goes_on(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    with (running_agent(endpoint, "baxter", speed=4.0) as (agent, watch),
          CommandSender(session, agent.robot_id) as op):
        op.raw(b"\x93not a command")
        bad = watch.wait(status("error"), "malformed payload reported")
        assert "malformed" in bad.detail
        op.raw(encode(Command(seq=1, sent_ns=0, deadman=True, ttl_ms=0, v=99)))
        bad = watch.wait(lambda s: "incompatible_version" in s.detail, "old peer reported")
        seq = op.send(("no_such_limb", "distal_11", "left-high", 2.0))
        bad = watch.after(seq, status("error"), "unknown limb reported")
        assert "unknown_limb" in bad.detail
        seq = op.send(("limb_11", "distal_11", "up-and-away", 2.0))
        bad = watch.after(seq, status("error"), "unknown direction reported")
        assert "unknown_direction" in bad.detail
        seq = op.send(drive=("left-high", 1.0))
        bad = watch.after(seq, status("error"), "a drive must be a middle horizontal")
        seq = op.send(drive=("left", 1.0))
        bad = watch.after(seq, status("error"), "a fixed base cannot drive")
        assert "cannot_translate" in bad.detail
        entry = databank.catalogue("baxter").limbs[0]
        seq = op.send((entry.limb, entry.origin, entry.directions[-1], 1.0))
        watch.after(seq, status("moving", "idle", "clamped"), "a good command still works")
        assert agent.stats.steps > 0 and agent._thread is not None and agent._thread.is_alive()
