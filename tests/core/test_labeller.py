"""The labeller proposes a valid eURDF from any plain URDF tree."""

import re
from pathlib import Path

import pytest

from kinesphere.eurdf import load_eurdf
from kinesphere.labeller import propose_eurdf
from kinesphere.platforms.platform import load_platform, platform_names
from support.paths import TOY_EURDF


def strip_labels(text: str) -> str:
    return re.sub(r"<body_part .*?</body_part>", "", text, flags=re.S)


def test_toy_proposal_is_valid_and_hierarchical(tmp_path: Path) -> None:
    plain = tmp_path / "toy.urdf"
    plain.write_text(strip_labels(TOY_EURDF.read_text()))
    e = load_eurdf(propose_eurdf(plain))
    assert e.C == ("c_1",)
    # the arm (higher, lateral ordering puts it before the central tail) is chain 1:
    # yaw, elbow, then wrist is the end effector location and gets no label.
    assert e.L == ("limb_11", "limb_12", "limb_21")
    assert e.limb_joints("limb_11") == ("yaw", "elbow", "wrist")
    assert e.limb_joints("limb_12") == ("elbow", "wrist")
    assert e.limb_joints("limb_21") == ("tail_joint",)


def test_merge_distance_groups_joint_locations(tmp_path: Path) -> None:
    plain = tmp_path / "toy.urdf"
    plain.write_text(strip_labels(TOY_EURDF.read_text()))
    e = load_eurdf(propose_eurdf(plain, merge_distance=0.5))
    # every arm joint is within 0.5 m of the previous one: one location, one limb
    assert [p.joints for p in e.distals if p.name == "distal_11"] == [("yaw", "elbow", "wrist")]


@pytest.mark.parametrize("name", platform_names())
def test_every_platform_relabels_into_a_valid_eurdf(name: str, tmp_path: Path) -> None:
    original = load_platform(name).eurdf
    assert original.path is not None
    plain = tmp_path / f"{name}.urdf"
    plain.write_text(strip_labels(original.path.read_text()))
    proposal = load_eurdf(propose_eurdf(plain))
    assert proposal.joint_names == original.joint_names
    assert proposal.C == ("c_1",)
    covered = {ln for p in (*proposal.core, *proposal.limbs) for ln in p.links}
    assert covered == set(proposal.urdf.link_map)
