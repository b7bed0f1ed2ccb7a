"""The labeller on every URDF example-robot-data ships: real third-party robots, labelled the
paper's way (torso joints in the core, one chain per arm, leg and head, hands at chain ends)."""

from pathlib import Path

import pytest

from kinesphere.errors import KinesphereError
from kinesphere.eurdf import Eurdf, load_eurdf
from kinesphere.labeller import propose_eurdf
from kinesphere.labeller_names import is_finger_name, is_limb_name
from kinesphere.platforms.cli import describe_dict
from support.byor import PANDA, TALOS, TIAGO, UR5, all_urdfs, robot_data

EMPTY = {"ur_description/urdf/ur3.urdf"}  # an xacro stub: a <robot> without links


def _rel(p: Path) -> str:
    return str(p.relative_to(robot_data()))


URDFS = [p for p in all_urdfs() if _rel(p) not in EMPTY]


def _label(rel: str) -> Eurdf:
    return load_eurdf(propose_eurdf(robot_data() / rel))


def _chains(e: Eurdf) -> dict[int, list[str]]:
    out: dict[int, list[str]] = {}
    for p in e.distals:
        if len(p.index) == 2:
            out.setdefault(p.index[0], []).append(p.name)
    return out


@pytest.mark.parametrize("path", URDFS, ids=_rel)
def test_every_shipped_urdf_gets_a_valid_structured_labelling(path: Path) -> None:
    e = load_eurdf(propose_eurdf(path))
    assert describe_dict(e)["dof"] == len(e.limits)
    joints = e.urdf.joint_map
    core_links = {ln for p in e.core for ln in p.links}
    firsts = [p for p in e.limbs if p.index[1] == 1]
    core_joints = {j for p in e.distals if len(p.index) == 1 for j in p.joints}
    for name in e.limits:
        child = joints[name].child
        owners = [p.name for p in firsts if child in p.links]
        # every actuated joint is in exactly one place: the core (a core joint location, or
        # a wheel/rotor the core carries) or one chain
        assert (child in core_links) != bool(owners), name
        assert len(owners) <= 1, (name, owners)
        if child in core_links:
            assert name in core_joints or not is_limb_name(name), name
    for chain in _chains(e).values():
        if is_finger_name(e.origin(chain[0]).joints[0]):
            continue  # the chain is a finger (a robot finger, a hand's fingers off its palm)
        for depth, distal in enumerate(chain, start=1):
            names = [str(j) for j in e.origin(distal).joints]
            if any(is_finger_name(n) for n in names) and not any(
                is_limb_name(n) for n in names
            ):
                # a chain never runs on into a finger: a finger location ends its chain
                assert depth == len(chain), (distal, names)


def test_an_empty_robot_is_a_clear_error() -> None:
    with pytest.raises(KinesphereError, match="no <link>"):
        propose_eurdf(robot_data() / "ur_description/urdf/ur3.urdf")


# Which first-level limbs (by alias) real robots get, and their core joints.
EXPECTED = {
    TALOS: (["right_arm", "left_arm", "right_leg", "left_leg", "head"],
            [["torso_1_joint", "torso_2_joint"]]),
    TIAGO: (["right_arm", "head"], [["torso_lift_joint"]]),
    PANDA: (["arm"], []),
    UR5: (["arm"], []),
    "icub_description/robots/icub.urdf": (
        ["right_arm", "left_arm", "right_leg", "left_leg", "head"],
        [["torso_pitch"], ["torso_roll", "torso_yaw"]]),
    "g1_description/urdf/g1_29dof_with_hand_rev_1_0.urdf": (
        ["right_arm", "left_arm", "right_leg", "left_leg"],
        [["waist_yaw_joint"], ["waist_roll_joint", "waist_pitch_joint"]]),
    "romeo_description/urdf/romeo.urdf": (
        ["right_arm", "left_arm", "right_leg", "left_leg", "head"], [["TrunkYaw"]]),
    "baxter_description/urdf/baxter.urdf": (["right_arm", "left_arm", "head"], []),
    "go1_description/urdf/go1.urdf": (
        ["front_right_leg", "front_left_leg", "hind_right_leg", "hind_left_leg"], []),
    "anymal_c_simple_description/urdf/anymal.urdf": (
        ["front_right_leg", "front_left_leg", "hind_right_leg", "hind_left_leg"], []),
    "pr2_description/urdf/pr2.urdf": (["right_arm", "left_arm"], [["torso_lift_joint"]]),
}


@pytest.mark.parametrize("rel", sorted(EXPECTED))
def test_real_robots_get_their_limbs_in_the_papers_order(rel: str) -> None:
    e = _label(rel)
    limbs, core_joints = EXPECTED[rel]
    firsts = [p.alias for p in e.limbs if p.index[1] == 1]
    assert firsts[: len(limbs)] == limbs
    assert [list(p.joints) for p in e.distals if len(p.index) == 1] == core_joints
    assert len(e.core) == len(core_joints) + 1  # the paper's Fig. 3: c_1, c_2 ... joined


def test_tiago_head_is_its_own_chain_and_the_arm_stops_at_the_hand() -> None:
    e = _label(TIAGO)
    assert e.limb_joints("head") == ("head_1_joint", "head_2_joint")
    arm = [p for p in e.limbs if p.index[0] == e.limb("right_arm").index[0]]
    hand = arm[-1]
    assert hand.alias == "right_hand"
    # the hand is one limb rooted at every joint leaving the palm, not one finger's chain
    palm = {j for j in e.origin(str(hand.distal)).joints}
    assert {"hand_thumb_joint", "hand_index_abd_joint", "hand_little_abd_joint"} <= palm
    for p in arm[:-1]:
        assert not any(is_finger_name(j) for j in e.origin(str(p.distal)).joints)


def test_mimic_joints_stay_mimics_and_a_gripper_ends_the_panda_arm() -> None:
    e = _label(PANDA)
    assert "panda_finger_joint2" not in e.limits  # a mimic is not a degree of freedom
    last = e.limbs[-1]
    assert last.alias == "gripper"
    assert e.origin(str(last.distal)).joints == ("panda_finger_joint1", "panda_finger_joint2")
    assert e.limb_joints("arm")[:7] == tuple(f"panda_joint{i}" for i in range(1, 8))


def test_encoding_declarations_and_unnamed_robots_are_read(tmp_path: Path) -> None:
    text = (robot_data() / UR5).read_bytes()
    assert text.startswith(b'<?xml version="1.0" encoding="utf-8"?>')
    e = _label(UR5)
    assert len(e.limits) == 6
    unnamed = tmp_path / "mybot.urdf"
    unnamed.write_bytes(text.replace(b'<robot name="ur5"', b"<robot"))
    assert load_eurdf(propose_eurdf(unnamed)).name == "mybot"


def test_limitless_revolutes_are_proposed_as_continuous() -> None:
    e = _label("quadruped_description/urdf/quadruped.urdf")
    assert e.limits["FL_KFE"].kind == "continuous"
