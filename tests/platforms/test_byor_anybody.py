"""``platform new`` on bodies nobody tuned it on (pybullet_data, example-robot-data): labels
from the tree first, bodies standing on their feet, Y-up files turned upright, a usable
neutral, spherical joints and missing meshes handled, MuJoCo's warnings gone."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from kinesphere.eurdf import load_eurdf
from kinesphere.labeller import propose_eurdf
from kinesphere.platforms.mjcf import build_spec
from kinesphere.platforms.platform import load_platform
from kinesphere.platforms.scaffold import new_platform
from kinesphere.services.ecl.chains import short_of
from support.byor import (
    A1,
    HUMANOID,
    IIWA,
    LAIKAGO,
    MINI_CHEETAH,
    MINITAUR,
    PANDA,
    R2D2,
    RACECAR,
    pybullet_data,
    robot_data,
    standing,
)


def test_a_word_in_a_joint_name_never_turns_a_leg_joint_into_core() -> None:
    e = load_eurdf(propose_eurdf(pybullet_data() / MINI_CHEETAH))
    assert [p.joints for p in e.distals if len(p.index) == 1] == []  # no core joint
    for side in ("fr", "fl", "hr", "hl"):
        leg = next(p for p in e.limbs if f"torso_to_abduct_{side}_j" in e.limb_joints(p.name))
        assert leg.index[1] == 1 and len(e.limb_joints(leg.name)) == 3
    assert {p.alias for p in e.limbs if p.index[1] == 1} == {
        "front_right_leg", "front_left_leg", "hind_right_leg", "hind_left_leg"}


def test_an_arm_ends_at_its_palm_and_never_moves_the_fingers() -> None:
    e = load_eurdf(propose_eurdf(robot_data() / PANDA))
    arm = e.limb("arm")
    assert arm.tip == "panda_hand" and e.tip_link("arm") == "panda_hand"
    assert e.limb_joints("arm") == tuple(f"panda_joint{i}" for i in range(1, 8))
    deeper = [p for p in e.limbs if p.index[0] == arm.index[0] and p.alias != "gripper"]
    for limb in deeper:
        assert "panda_finger_joint1" not in e.limb_joints(limb.name)
    assert "panda_finger_joint1" in e.limb_joints("gripper")


def test_steered_wheels_belong_to_the_base() -> None:
    e = load_eurdf(propose_eurdf(pybullet_data() / RACECAR))
    assert e.limbs == ()
    core = {ln for p in e.core for ln in p.links}
    assert {"left_steering_hinge", "left_front_wheel", "right_rear_wheel"} <= core


def test_front_and_back_legs_and_a_central_head_are_named_right() -> None:
    e = load_eurdf(propose_eurdf(pybullet_data() / MINITAUR))
    firsts = {p.alias for p in e.limbs if p.index[1] == 1}
    assert {"front_right_leg", "front_left_leg", "hind_right_leg", "hind_left_leg"} <= firsts
    assert "motor_back_rightR_joint" in e.limb_joints("hind_right_leg")
    r2d2 = load_eurdf(propose_eurdf(pybullet_data() / R2D2))
    assert r2d2.limb("head").alias == "head"
    assert "head_swivel" in r2d2.limb_joints("head")


def test_a_quadruped_stands_on_its_feet_with_a_legged_base(tmp_path: Path) -> None:
    made = new_platform("a1", pybullet_data() / A1, tmp_path)
    assert made.base_kind == "legged" and load_platform(str(made.folder)).base.holonomic
    low, feet = standing(made.folder)
    assert 0.0 <= low < 0.001
    assert feet == ["FL_toe", "FR_toe", "RL_toe", "RR_toe"]
    assert "translation_step" in (made.folder / "vsam.toml").read_text()


def test_a_y_up_file_is_turned_upright(tmp_path: Path) -> None:
    made = new_platform("laikago", pybullet_data() / LAIKAGO, tmp_path)
    assert made.up == "y" and any("up axis is y" in m for m in made.mends)
    assert made.base_kind == "legged"
    low, feet = standing(made.folder)
    assert 0.0 <= low < 0.001 and len(feet) == 4
    assert len(made.standing_on) == 4
    named = new_platform("upright", pybullet_data() / LAIKAGO, tmp_path, up="z")
    assert len(named.standing_on) == 2  # told z: it lies on its side, on one pair of legs


def test_a_stretched_zero_gets_a_proposed_neutral_and_zero_stays_available(
    tmp_path: Path
) -> None:
    made = new_platform("iiwa", pybullet_data() / IIWA, tmp_path)
    (arm,) = [p for p in made.neutral if p.joints]
    assert arm.stretched and arm.open > arm.zero_open
    plat = load_platform(str(made.folder))
    assert plat.neutral == arm.joints
    assert "keeps zero" in (made.folder / "platform.toml").read_text()
    zero = new_platform("iiwa-zero", pybullet_data() / IIWA, tmp_path, neutral="zero")
    assert load_platform(str(zero.folder)).neutral == {}


def test_spherical_joints_are_three_revolutes(tmp_path: Path) -> None:
    made = new_platform("humanoid", pybullet_data() / HUMANOID, tmp_path)
    e = made.eurdf
    for axis in "xyz":
        assert e.limits[f"chest_{axis}"].kind in ("revolute", "continuous")
    assert any("joint neck: spherical, read as three revolutes" in m for m in made.mends)


def test_a_missing_mesh_is_said_and_stood_in_for_by_a_box_of_its_inertia(
    tmp_path: Path
) -> None:
    text = (pybullet_data() / A1).read_text().replace("meshes/calf.obj", "gone/calf.obj")
    urdf = tmp_path / "a1.urdf"  # beside no meshes at all
    urdf.write_text(text)
    made = new_platform("partial", urdf, tmp_path / "out")
    assert len(made.meshes.missing) == 13  # all of them: the copy sits apart from its meshes
    lines = [m for m in made.mends if "not found; stand-in box" in m]
    assert len(lines) == 13 and any("gone/calf.obj" in m for m in lines)
    calf = made.eurdf.urdf.link_map["FR_lower"]
    geometry = calf.visuals[0].geometry
    assert geometry is not None and geometry.box is not None


def test_meshes_compile_without_third_party_warnings(tmp_path: Path) -> None:
    made = new_platform("panda", pybullet_data() / "franka_panda/panda.urdf", tmp_path)
    assert made.meshes.converted > 0
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        build_spec(load_platform(str(made.folder))).compile()
    assert caught == []


@pytest.mark.parametrize(("value", "text"), [(0.8497, "0.8497 < 0.85"), (0.84, "0.84 < 0.85"),
                                             (0.849999, "0.849999 < 0.85")])
def test_a_reason_shows_the_digits_that_make_it_true(value: float, text: str) -> None:
    assert short_of(value, 0.85) == text
    shown = float(text.split(" < ")[0])
    assert shown < 0.85 and np.isclose(shown, value)
