"""Acks over the wire: every command a robot receives is answered on ``{p}/robot/{id}/ack``,
naming it by ``(sender, session, seq)``, and RobotState says who holds and who latched it.

Real Zenoh, the real databank, in-process agents on MuJoCo.
"""

from __future__ import annotations

import math

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.protocol import Pose, SpatialCommand
from support.agents import (
    AckWatch,
    CommandSender,
    DatabankProcess,
    far,
    joints_close,
    running_agent,
)
from support.network import Hub


def test_a_command_is_accepted_moves_and_is_reached_or_superseded(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    cat = databank.catalogue("baxter")
    first, second = far(cat, 0), far(cat, -1)
    target = databank.query("baxter", SpatialCommand(*second))
    with (AckWatch(session, "baxter") as acks,
          running_agent(endpoint, "baxter", speed=2.0) as (agent, watch),
          CommandSender(session, agent.robot_id, sender="ann", client_session="s-1") as op):
        seq = op.send(first)
        assert acks.of("ann", seq, "accepted").session == "s-1"
        acks.of("ann", seq, "moving")
        reached = acks.of("ann", seq, "reached")
        assert acks.stages("ann", seq) == ["accepted", "moving", "reached"]
        assert reached.robot_id == "baxter" and reached.stamp_ns > 0

        replaced = op.send(second)  # mid-motion, a different target
        acks.of("ann", replaced, "moving")
        stream = [op.send(first) for _ in range(5)]  # back to back: coalesced in the inbox
        acks.of("ann", replaced, "superseded")
        acks.of("ann", stream[-1], "reached", "the stream's last command reached")
        for s in stream:  # each is answered: acted on, or replaced by the next before that
            assert acks.stages("ann", s)[0] in ("accepted", "superseded"), s
        assert [s for s in stream if "reached" in acks.stages("ann", s)] == [stream[-1]]
        seq = op.send(second)
        state = watch.after(seq, lambda s: s.status == "idle", "at the second pose")
        assert joints_close(state, agent.controller.joints.clamp(target.joints)[0], 5e-3)


def test_commands_that_move_nothing_get_one_ack_and_the_state_names_who(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    cat = databank.catalogue("youbot")
    with (AckWatch(session, "yb-acks") as acks,
          running_agent(endpoint, "youbot", robot_id="yb-acks", speed=2.0,
                        groups=("field",)) as (agent, watch),
          CommandSender(session, agent.robot_id, sender="ann", client_session="a") as op,
          CommandSender(session, agent.robot_id, sender="bob", client_session="b") as panic):

        seq = op.send(lease="acquire")
        assert acks.of("ann", seq, "leased").lease_holder == "ann"
        state = watch.after(seq, lambda s: s.lease_holder == "ann", "lease in the state")
        assert state.groups == ["field"]

        seq = op.send(("no_such_limb", "distal_11", "left-high", 2.0))
        bad = acks.of("ann", seq, "rejected")
        assert bad.code == "unknown_limb" and "no_such_limb" in bad.detail

        stale = op.send(far(cat), seq=seq - 1)
        assert acks.of("ann", stale, "rejected").code == "stale"
        watch.wait(lambda s: s.dropped >= 1, "the stale command counted as dropped")

        seq = op.send(deadman=False)
        assert acks.of("ann", seq, "holding").lease_holder == "ann"
        seq = op.send(stop=True)
        acks.of("ann", seq, "stopped")

        seq = panic.send(estop=True)
        acks.of("bob", seq, "estopped")
        watch.after(0, lambda s: s.status == "estop" and s.estop_by == "bob", "latched by bob")
        seq = op.send(far(cat), ttl_ms=1000)
        latched = acks.of("ann", seq, "rejected")
        assert latched.code == "estopped" and "bob" in latched.detail
        seq = op.send(release=True)  # bob's latch: ann's release clears nothing
        assert acks.of("ann", seq, "rejected").code == "estopped"
        seq = panic.send(release=True)
        acks.of("bob", seq, "released")
        watch.wait(lambda s: s.status != "estop" and s.estop_by == "", "released")

        seq = op.send(lease="release")
        assert acks.of("ann", seq, "leased").lease_holder == ""


def test_substitutions_and_databank_errors_are_relayed_as_the_databank_said(
    hub: Hub, databank: DatabankProcess
) -> None:
    """A direction a limb lacks: whatever the databank answers (the nearest direction it has,
    or ``direction_unavailable``), the robot's ack and state say the same."""
    session, endpoint = hub
    cat = databank.catalogue("baxter")
    entry = min(cat.limbs, key=lambda e: len(e.directions))
    missing = next(d.slug for d in Direction.pulls() if d.slug not in entry.directions)
    part = (entry.limb, entry.origin, missing, 2.0)
    try:
        answer: Pose | KinesphereError = databank.query("baxter", SpatialCommand(*part))
    except KinesphereError as exc:
        answer = exc
    with (AckWatch(session, "bx-subs") as acks,
          running_agent(endpoint, "baxter", robot_id="bx-subs", speed=2.0) as (agent, watch),
          CommandSender(session, agent.robot_id, sender="ann") as op):
        seq = op.send(part)
        first = acks.wait(lambda a: a.seq == seq and a.stage in ("accepted", "rejected"),
                          "the verdict on a missing direction")
        if isinstance(answer, KinesphereError):
            assert first.stage == "rejected" and first.code == answer.code
        else:
            assert first.stage == "accepted" and first.substitutions == answer.substitutions
            state = watch.after(seq, lambda s: True, "state after the substitution")
            assert state.substitutions == answer.substitutions


def test_a_translation_beyond_the_robots_maximum_is_refused_and_nothing_moves(
    hub: Hub, databank: DatabankProcess
) -> None:
    """Whoever refuses a huge size (the databank past its ``max_size``, or the robot past its
    maximum translation per command), the base does not move and state keeps flowing."""
    session, endpoint = hub
    cat = databank.catalogue("youbot")
    core = cat.core[0]
    step = cat.translation_step or 0.25
    with (AckWatch(session, "yb-far") as acks,
          running_agent(endpoint, "youbot", robot_id="yb-far", speed=2.0,
                        max_translation_m=1.0) as (agent, watch),
          CommandSender(session, agent.robot_id, sender="ann") as op):
        for size in (1e10, 1e7, 1e4, 1.5 / step):
            seq = op.send((core, core, "forward-middle", size), ttl_ms=0)
            refused = acks.of("ann", seq, "rejected", f"size {size:g} refused")
            assert refused.code == "size_out_of_range", refused
        assert "at most 1 m" in refused.detail, "the robot's own bound"
        later = watch.after(seq, lambda s: s.status == "error", "refusal reported")
        more = watch.wait(lambda s: s.seq > later.seq + 10, "state keeps flowing")
        assert math.hypot(*more.base_pose[:2]) < 1e-6 and not agent.controller.moving
        seq = op.send((core, core, "forward-middle", 0.5 / step), ttl_ms=0)
        watch.after(seq, lambda s: s.status == "idle" and abs(s.base_pose[0] - 0.5) < 5e-3,
                    "a modest translation still works")
        acks.of("ann", seq, "reached")
        assert acks.stages("ann", seq) == ["accepted", "moving", "reached"]
