"""Base motion with articulation: beyond-far reaches translate while the arm moves, drives
carry on while the arm sweeps, and a limbless robot goes where a core command sends it."""

from __future__ import annotations

import math

from kinesphere.protocol import SpatialCommand
from support.agents import (
    CommandSender,
    DatabankProcess,
    Trace,
    far,
    joints_close,
    overlap,
    running_agent,
)
from support.network import Hub


def test_translation_and_articulation_overlap_in_time(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    cat = databank.catalogue("youbot")
    assert cat.can_translate and cat.translation_step
    part = far(cat, horizontal=True, past=2.0)
    pose = databank.query("youbot", SpatialCommand(*part))
    goal = pose.translation
    assert goal is not None and pose.joints
    trace = Trace()
    with (running_agent(endpoint, "youbot", speed=4.0, trace=trace) as (agent, watch),
          CommandSender(session, agent.robot_id) as op):
        target, _ = agent.controller.joints.clamp(pose.joints)
        seq = op.send(part)
        done = watch.after(
            seq,
            lambda s: s.status == "idle" and joints_close(s, target, 5e-3)
            and math.dist(s.base_pose[:2], goal[:2]) < 5e-3,
            "arm at the pose and base translated",
        )
    assert abs(done.base_pose[2]) < 1e-3, "an omni base translates without turning"
    start, end = overlap(trace)
    assert end - start > 0.2, f"joints and base should move together, overlap {start}..{end}"


def test_drive_while_the_arm_sweeps(hub: Hub, databank: DatabankProcess) -> None:
    """The PackBot sweep: drive forward while the arm goes low left, then low right."""
    session, endpoint = hub
    sweeps = [(e, pair) for pair in (("left-low", "right-low"),
                                     ("left-forward-low", "right-forward-low"))
              for e in databank.catalogue("packbot").limbs if set(pair) <= set(e.directions)]
    assert sweeps, "the packbot cannot sweep low left-right"
    entry, lows = sweeps[0]
    trace = Trace()
    with (running_agent(endpoint, "packbot", speed=2.0, trace=trace) as (agent, watch),
          CommandSender(session, agent.robot_id) as op):
        for d in (lows[0], lows[-1]):
            pose = databank.query("packbot", SpatialCommand(entry.limb, entry.origin, d, 2.0))
            target, _ = agent.controller.joints.clamp(pose.joints)
            seq = op.send((entry.limb, entry.origin, d, 2.0), drive=("forward", 0.3),
                          ttl_ms=2000)
            while not joints_close(watch.after(seq, lambda s: True, "a state"), target, 5e-3):
                seq = op.send((entry.limb, entry.origin, d, 2.0), drive=("forward", 0.3),
                              ttl_ms=2000)  # streamed, like the gamepad client
        seq = op.send(stop=True)
        stopped = watch.after(seq, lambda s: s.status == "stopped"
                              and not agent.controller.moving, "stopped")
    start, end = overlap(trace)
    assert end - start > 0.2
    assert stopped.base_pose[0] > 0.1, "drove forward"
    assert abs(stopped.base_pose[1]) < 1e-3, "a skid base does not slide sideways"


def test_limbless_robot_follows_a_core_command(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    cat = databank.catalogue("khepera")
    core = cat.core[0]
    part = SpatialCommand(core, core, "left-forward-middle", 3.0)
    pose = databank.query("khepera", part)
    goal = pose.translation
    assert goal is not None
    with (running_agent(endpoint, "khepera", speed=4.0) as (agent, watch),
          CommandSender(session, agent.robot_id) as op):
        seq = op.send(part)
        done = watch.after(
            seq, lambda s: s.status == "idle"
            and math.dist(s.base_pose[:2], goal[:2]) < 5e-3,
            "khepera at the translated position")
    assert abs(done.base_pose[2] - math.pi / 4) < 5e-3, "a diff base turns towards the goal"
