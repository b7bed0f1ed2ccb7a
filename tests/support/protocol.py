"""For the protocol tests: one sample of every wire message."""

from __future__ import annotations

import math

from kinesphere import protocol as pr

SPATIAL = pr.SpatialCommand("limb_11", "distal_11", "left-high", 2.5)

SAMPLES: list[pr.Message] = [
    pr.Pose(
        platform="baxter",
        limb="limb_11",
        origin="distal_11",
        direction="left-high",
        size=3.5,
        joints={"right_s0": -0.25, "right_s1": 0.5},
        translation=[0.1, -0.2, 0.0],
        k_id=7,
        p_id=None,
    ),
    pr.Pose(
        platform="nao",
        limb=pr.COMPOUND,
        origin=pr.COMPOUND,
        direction=pr.COMPOUND,
        size=0.0,
        joints={"HeadYaw": 0.3},
        k_id=pr.NO_ID,
        p_id=None,
        parts=[SPATIAL, pr.SpatialCommand("limb_51", "distal_51", "place-high", 1.0)],
    ),
    pr.Catalogue(
        platform="youbot",
        core=["c_1"],
        limbs=[pr.LimbEntry("limb_11", "distal_11", ["forward-middle", "place-high"], [1, 2, 3])],
        joints=[pr.BodyJoint("arm_joint_1", -2.9, 2.9, 1.5)],
        translation_step=0.25,
        can_translate=True,
        directions_for_core=["forward-middle", "left-middle"],
        sizes=[1, 2, 3],
        aliases={"arm": "limb_11"},
        version="sha1:abc",
    ),
    pr.Command(
        seq=42,
        sent_ns=1_700_000_000_000_000_000,
        parts=[SPATIAL],
        drive=pr.Drive("left-forward-middle", 0.75),
        deadman=True,
        ttl_ms=250,
        estop=False,
        stop=True,
        sender="pad-1",
    ),
    pr.RobotState(
        robot_id="r1",
        platform="baxter",
        seq=9,
        stamp_ns=123,
        joint_names=["a", "b"],
        q=[0.1, 0.2],
        qd=[0.0, -1.0],
        base_pose=[1.0, 2.0, math.pi / 2],
        status=pr.Status.CLAMPED,
        last_command_seq=41,
        detail="b at upper limit",
        clamped=["b"],
    ),
    pr.Error(code="unknown_limb", message="baxter has no limb 'tail'"),
    pr.RecordRequest(
        limb="limb_11", origin="distal_11", direction="forward-high", size=2, joints={"a": 1.25}
    ),
    pr.CompoundRequest(parts=[SPATIAL, SPATIAL], last_wins=True),
    pr.Ack(
        robot_id="r1",
        sender="pad-1",
        session="5f0c",
        seq=42,
        stage=pr.AckStage.REJECTED,
        code="lease_held",
        detail="lease held by pad-2",
        stamp_ns=124,
        substitutions=[pr.Substitution("limb_11", "distal_11", "left-low", "left-forward-low",
                                       45.0)],
        lease_holder="pad-2",
        measured_angle=41.5,
    ),
    pr.BodyModel(
        platform="youbot",
        eurdf="<robot name='youbot'/>",
        base_kind="omni",
        neutral={"arm_joint_1": 0.0},
        version="sha1:def",
    ),
    pr.Command(
        seq=43,
        sent_ns=1_700_000_000_000_000_001,
        parts=[pr.SpatialCommand("arm", "shoulder", "left-low", 2.0, exact=True)],
        drive=pr.Drive("forward-middle", 0.5, forward=0.5, left=-0.25, yaw=0.3),
        deadman=True,
        ttl_ms=300,
        sender="pad-1",
        session="5f0c",
        lease=pr.LeaseAction.TAKE,
    ),
    pr.FleetEstops(holder="3f2a9c", estops=[
        pr.FleetEstop("alice@lab", engaged=True, sent_ns=1_700_000_000_000_000_002),
        pr.FleetEstop("bob@lab", engaged=False, sent_ns=1_700_000_000_000_000_003)]),
    pr.Presence(robot_id="yb-1", platform="youbot", host="robot-pc", pid=4242,
                started_ns=1_700_000_000_000_000_004, zid="3f2a9c"),
]
