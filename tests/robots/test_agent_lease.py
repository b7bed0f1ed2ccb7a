"""Control leases over the wire: two operators streaming to one robot, only the holder moves
it; the other is refused naming the holder; e-stop from anyone; take-over; expiry.

Real time (``speed=1``): the lease timeout against silent clients is the point.
"""

from __future__ import annotations

import time
from functools import partial

import numpy as np

from kinesphere.protocol import Ack, Drive
from kinesphere.robots.agent.lease import LEASE_TIMEOUT_S
from support.agents import (
    AckWatch,
    CommandSender,
    DatabankProcess,
    StateWatch,
    newer_than,
    running_agent,
)
from support.network import Hub

TTL_MS = 500


def _verdict_on(sender: str, seq: int, ack: Ack) -> bool:
    return ack.sender == sender and ack.seq == seq and ack.stage in ("accepted", "rejected")


def streams(ann: CommandSender, bob: CommandSender, watch: StateWatch, n: int
            ) -> tuple[list[int], list[int]]:
    """Both operators stream: Ann drives forward, Bob drives back; one command each per
    state received."""
    a_seqs, b_seqs = [], []
    for _ in range(n):
        a_seqs.append(ann.send(drive=Drive(forward=0.6), ttl_ms=TTL_MS))
        b_seqs.append(bob.send(drive=Drive(forward=-0.6), ttl_ms=TTL_MS))
        watch.after(a_seqs[-1], lambda s: True, "a state")
    return a_seqs, b_seqs


def test_two_operators_only_the_holder_moves_the_robot(
    hub: Hub, databank: DatabankProcess
) -> None:
    session, endpoint = hub
    with (AckWatch(session, "yb-lease") as acks,
          running_agent(endpoint, "youbot", robot_id="yb-lease", speed=1.0) as (agent, watch),
          CommandSender(session, agent.robot_id, sender="ann", client_session="a1") as ann,
          CommandSender(session, agent.robot_id, sender="bob", client_session="b1") as bob):
        a_seqs, b_seqs = streams(ann, bob, watch, 40)
        state = watch.after(a_seqs[-1], lambda s: True, "after both streams")
        assert state.lease_holder == "ann" and state.base_pose[0] > 0.02, "Ann drove forward"
        refusals = [acks.of("bob", s, "rejected") for s in b_seqs[-5:]]
        assert all(r.code == "lease_held" and "ann" in r.detail and r.lease_holder == "ann"
                   for r in refusals)
        assert not any("accepted" in acks.stages("bob", s) for s in b_seqs)
        xs = np.array([s.base_pose[0] for s in watch.states])
        assert np.all(np.diff(xs) >= -1e-4), "Bob's stream never pulled the robot back"

        # e-stop from the non-holder stops the robot at once
        seq = bob.send(estop=True)
        acks.of("bob", seq, "estopped")
        halted = watch.wait(lambda s: s.status == "estop" and not agent.controller.moving,
                            "halted by Bob's e-stop")
        assert halted.estop_by == "bob" and halted.lease_holder == "ann"
        seq = ann.send(drive=Drive(forward=0.6), ttl_ms=TTL_MS)
        assert acks.of("ann", seq, "rejected").code == "estopped"
        seq = bob.send(release=True)
        acks.of("bob", seq, "released")

        # take-over: Ann is told, and refused from then on
        last_ann = ann.send(drive=Drive(forward=0.6), ttl_ms=TTL_MS)
        acks.of("ann", last_ann, "accepted")
        seq = bob.send(lease="take")
        assert acks.of("bob", seq, "leased").lease_holder == "bob"
        told = acks.wait(lambda a: a.sender == "ann" and a.seq == last_ann
                         and a.stage == "rejected", "Ann told of the take-over")
        assert told.code == "lease_held" and "bob" in told.detail
        seq = ann.send(drive=Drive(forward=0.6), ttl_ms=TTL_MS)
        refused = acks.of("ann", seq, "rejected")
        assert refused.code == "lease_held" and refused.lease_holder == "bob"
        seq = bob.send(drive=Drive(forward=-0.6), ttl_ms=TTL_MS)
        acks.of("bob", seq, "accepted")
        watch.after(seq, lambda s: s.lease_holder == "bob", "Bob holds the lease")

        # Bob goes silent: the lease expires on time and Ann acquires it
        quiet = time.monotonic()
        while True:
            seq = ann.send(drive=Drive(forward=0.6), ttl_ms=TTL_MS)
            a = acks.wait(partial(_verdict_on, "ann", seq), "Ann's verdict")
            if a.stage == "accepted":
                break
            now = watch.states[-1].seq
            watch.wait(partial(newer_than, now), "the next state")
        waited = time.monotonic() - quiet
        assert LEASE_TIMEOUT_S - 0.1 <= waited <= LEASE_TIMEOUT_S + 2.0, waited
        assert a.lease_holder == "ann"
        ann.send(stop=True)
