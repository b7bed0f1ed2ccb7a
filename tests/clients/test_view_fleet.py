"""What the view knows of each robot, over real Zenoh: who is alive, its state, and which
commands reach it (its own key, every robot's, and a group's: the robots whose state lists
that group), with states on another robot's key ignored."""

from __future__ import annotations

import time

import msgspec

from kinesphere import protocol as pr
from kinesphere import zconfig
from kinesphere.clients.view.app import describe
from kinesphere.clients.view.fleet import Fleet, Robot
from support.network import OWN_KEYS
from support.wait import until

PART = pr.SpatialCommand("limb_11", "distal_11", "left-high", 3)


def state(rid: str, groups: list[str], seq: int = 0) -> pr.RobotState:
    return pr.RobotState(robot_id=rid, platform="baxter", seq=seq, stamp_ns=time.time_ns(),
                         joint_names=["a"], q=[0.0], qd=[0.0], base_pose=[0.0, 0.0, 0.0],
                         status="idle", last_command_seq=-1, groups=groups)


def seq_of(fleet: Fleet, rid: str) -> int:
    st = fleet.snapshot()[rid].state
    assert st is not None
    return st.seq


def command(seq: int, **kw: object) -> pr.Command:
    return msgspec.structs.replace(
        pr.Command(seq=seq, sent_ns=time.time_ns(), ttl_ms=300, sender="t", deadman=True), **kw)


def test_commands_reach_the_robots_they_address() -> None:
    with zconfig.loopback_hub() as (hub, endpoint), \
            zconfig.session(config=zconfig.loopback_config(endpoint)) as robots:
        fleet = Fleet(hub, OWN_KEYS)
        try:
            tokens = {rid: robots.liveliness().declare_token(OWN_KEYS.alive_robot(rid))
                      for rid in ("r1", "r2")}
            until(lambda: set(fleet.snapshot()) == {"r1", "r2"}, 20.0, "both robots")
            robots.put(OWN_KEYS.state("r1"), pr.encode(state("r1", ["arms"])))
            robots.put(OWN_KEYS.state("r2"), pr.encode(state("r2", [])))
            until(lambda: all(r.state for r in fleet.snapshot().values()), 20.0, "every state")
            robots.put(OWN_KEYS.state("r1"), pr.encode(state("r2", ["arms"], seq=7)))  # spoofed
            robots.put(OWN_KEYS.state("r2"), pr.encode(state("r2", [], seq=1)))  # after it
            until(lambda: seq_of(fleet, "r2") == 1, 20.0, "r2's command 1")
            assert seq_of(fleet, "r1") == 0, "a state on r1's key claiming to be r2 is ignored"

            move = command(1, parts=[PART], deadman=True)
            robots.put(OWN_KEYS.group_command("arms"), pr.encode(move))
            ack = pr.Ack(robot_id="r2", sender="t", seq=1, stage=pr.AckStage.ACCEPTED,
                         stamp_ns=time.time_ns())
            robots.put(OWN_KEYS.ack("r2"), pr.encode(ack))  # after the group command
            until(lambda: fleet.snapshot()["r1"].motion == move, 20.0, "r1's motion")
            until(lambda: fleet.snapshot()["r2"].ack == ack, 20.0, "r2's ack")
            assert fleet.snapshot()["r2"].command is None, "r2 is not in the group"
            own = command(2, parts=[PART], deadman=True)
            robots.put(OWN_KEYS.command("r2"), pr.encode(own))
            until(lambda: fleet.snapshot()["r2"].motion == own, 20.0, "r2's own motion")
            assert fleet.snapshot()["r1"].motion == move, "r2's command is not r1's"

            stop = command(3, deadman=False, stop=True)
            robots.put(OWN_KEYS.command("*"), pr.encode(stop))
            until(lambda: all(r.command == stop and r.motion is None
                                   for r in fleet.snapshot().values()), 20.0, "the stop everywhere")

            zconfig.undeclare(tokens.pop("r2"))
            until(lambda: set(fleet.snapshot()) == {"r1"}, 20.0, "r2 gone")
            zconfig.undeclare(tokens.pop("r1"))
        finally:
            fleet.close()


def test_an_estop_is_shown_as_what_the_robot_did_not_what_was_sent() -> None:
    """The view saw an e-stop go to every robot; one latched it, one did not: only the one
    that latched shows it as its command."""
    stopped = msgspec.structs.replace(state("r1", []), status="estop", estop_by="t")
    now = time.monotonic()
    latched = Robot("r1", state=stopped, state_at=now,
                    command=command(4, estop=True, deadman=False))
    missed = Robot("r2", state=state("r2", []), state_at=now,
                   command=command(4, estop=True, deadman=False))
    assert describe(latched, None) == ("estop by t", "E-STOP")
    assert describe(missed, None)[1] == "E-STOP sent, but this robot reports no latch"
    gone = Robot("r1", state=stopped, state_at=now - 5.0)
    assert describe(gone, None)[0] == "silent (last said: estop by t)"
