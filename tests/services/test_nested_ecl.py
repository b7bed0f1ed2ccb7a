"""Nested parts in the ECL: a limb and a limb inside it pointed together, each segment where
told, measured by forward kinematics with yourdfpy (not the solver's MuJoCo model); the same
part twice still a conflict; sizes, refusals, a lifted leg standing on the other one (or refused
when it cannot), limits, determinism and the cache."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.mjcf import platform_model
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import NO_ID, SpatialCommand
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.measure import Fk
from kinesphere.services.ecl.nested import (
    ENTRY_BYTES,
    SOLUTION_BYTES,
    SOLUTIONS,
    Segment,
    Solution,
    sized,
    solution_bytes,
)
from support.ecl import build
from support.nested import MeasuredBody, SegmentEnds, degrees, unit
from support.paths import TOY

UPPER_ARM, FOREARM = SegmentEnds("distal_11", "distal_12"), SegmentEnds("distal_12", "limb_12")
THIGH, SHIN = SegmentEnds("distal_31", "distal_32"), SegmentEnds("distal_32", "limb_32")
LIFTED = frozenset(load_platform("nao").eurdf.limb_joints("limb_31"))


def arm_pair(d1: str, d2: str, size: float = 3) -> list[SpatialCommand]:
    return [SpatialCommand("right_upper_arm", "right_shoulder", d1, size),
            SpatialCommand("right_forearm", "right_elbow", d2, size)]


def leg_pair(thigh: str, shin: str, size: float = 3) -> list[SpatialCommand]:
    return [SpatialCommand("right_thigh", "right_hip", thigh, size),
            SpatialCommand("right_shin", "right_knee", shin, size)]


def measured(body: MeasuredBody, joints: dict[str, float], seg: SegmentEnds) -> np.ndarray:
    body.pose(joints)
    return body.direction(seg)


@pytest.fixture(scope="module")
def baxter() -> Ecl:
    return Ecl.open("baxter")


@pytest.fixture(scope="module")
def nao() -> Ecl:
    return Ecl.open("nao")


def test_a_brought_robots_arm_and_forearm_are_pointed_together(tmp_path: Path) -> None:
    """The toy arm (a platform folder, as a user brings one): its upper arm turns only about
    itself (always up), its forearm anywhere; both named at once is no conflict."""
    db = tmp_path / "toy.sqlite"
    build(db)
    ecl = Ecl.open(str(TOY), db)
    body = MeasuredBody(str(TOY))
    for d in ("forward-middle", "left-high", "right-forward-low"):
        pose = ecl.compound([("arm", "shoulder", "place-high", 3), ("forearm", "elbow_loc", d, 3)])
        assert set(pose.joints) == {"yaw", "elbow", "wrist"}
        assert [p.limb for p in pose.parts] == ["limb_11", "limb_12"]
        assert degrees(measured(body, pose.joints, UPPER_ARM), unit(Direction.PLACE_HIGH)) < 1
        assert degrees(measured(body, pose.joints, FOREARM), unit(Direction.parse(d))) < 5, d


def test_baxters_forearm_points_where_told_whatever_the_upper_arm_does(baxter: Ecl) -> None:
    """What last-wins joins got wrong (the forearm's stored row assumes a hanging upper arm)."""
    body = MeasuredBody("baxter")
    for d1, d2 in (("forward-high", "left-forward-middle"), ("right-middle", "forward-low"),
                   ("right-forward-low", "right-high")):
        pose = baxter.compound(arm_pair(d1, d2))
        upper = float(degrees(measured(body, pose.joints, UPPER_ARM), unit(Direction.parse(d1))))
        fore = float(degrees(measured(body, pose.joints, FOREARM), unit(Direction.parse(d2))))
        assert upper < 15 and fore < 15
        # the answer says how far its worst segment points from what was asked
        assert pose.measured_angle == pytest.approx(max(upper, fore), abs=6)
        limits = body.eurdf.limits
        assert all(limits[j].lower <= v <= limits[j].upper for j, v in pose.joints.items())
        assert [w.word for w in pose.words] == ["right_upper_arm"]
        assert pose.words[0].label == "limb_11" and pose.words[0].end == "distal_12"


def test_two_arms_crossed_in_front_pass_one_another(baxter: Ecl) -> None:
    """Crossed forearms (LabanotationSuite's ``think``: upper arms forward-low, each forearm
    toward the other side, high): each arm answered alone is clean, but the two answers
    mirrored put Baxter's forearms through each other. The arm answered second is pointed
    with the first one in place, so the joined pose touches nothing (MuJoCo's contacts) and
    still points every segment where told (yourdfpy)."""
    body = MeasuredBody("baxter")
    left_upper, left_fore = SegmentEnds("distal_21", "distal_22"), SegmentEnds("distal_22",
                                                                              "limb_22")
    parts = [*arm_pair("forward-low", "left-forward-high"),
             SpatialCommand("left_upper_arm", "left_shoulder", "forward-low", 3),
             SpatialCommand("left_forearm", "left_elbow", "right-forward-high", 3)]
    pose = baxter.compound(parts)
    pm = platform_model("baxter")
    data = mujoco.MjData(pm.model)
    data.qpos[:] = pm.qpos(pose.joints)
    mujoco.mj_kinematics(pm.model, data)
    mujoco.mj_collision(pm.model, data)
    assert data.ncon == 0, [(pm.model.body(pm.model.geom_bodyid[c.geom1]).name,
                             pm.model.body(pm.model.geom_bodyid[c.geom2]).name)
                            for c in data.contact[: data.ncon]]
    for seg, d in ((UPPER_ARM, "forward-low"), (FOREARM, "left-forward-high"),
                   (left_upper, "forward-low"), (left_fore, "right-forward-high")):
        assert float(degrees(measured(body, pose.joints, seg), unit(Direction.parse(d)))) < 15
    alone = baxter.compound(parts[2:])  # the left arm alone is answered as before
    assert alone.joints != {j: pose.joints[j] for j in alone.joints}


def test_the_same_part_twice_is_still_a_conflict(nao: Ecl) -> None:
    twice = [SpatialCommand("right_forearm", "right_elbow", "forward-middle", 3),
             SpatialCommand("limb_12", "distal_12", "back-low", 3)]
    with pytest.raises(KinesphereError) as err:
        nao.compound(twice)
    assert err.value.code == "conflict" and "both move limb_12" in err.value.message
    later = nao.compound(twice, last_wins=True)
    assert later.joints == nao.query("limb_12", "distal_12", "back-low", 3).joints
    with pytest.raises(KinesphereError) as err:  # an upper arm is the arm: the same part
        nao.compound([SpatialCommand("right_arm", "right_shoulder", "forward-high", 3),
                      SpatialCommand("right_upper_arm", "right_shoulder", "forward-low", 3)])
    assert err.value.code == "conflict"


def test_a_cut_limb_alone_is_answered_on_its_pose_key(nao: Ecl) -> None:
    pose = nao.query("right_upper_arm", "right_shoulder", "forward-high", 3)
    assert (pose.limb, pose.origin, pose.direction, pose.k_id) == (
        "limb_11", "distal_11", "forward-high", NO_ID)
    assert [(w.word, w.label, w.end) for w in pose.words] == [
        ("right_upper_arm", "limb_11", "distal_12")]
    body = MeasuredBody("nao")
    assert degrees(measured(body, pose.joints, UPPER_ARM), unit(Direction.FORWARD_HIGH)) < 15
    assert nao.solves([("right_upper_arm", "right_shoulder", "forward-high", 3)])
    assert nao.solves(arm_pair("forward-high", "left-middle"))
    assert not nao.solves([("right_arm", "right_shoulder", "forward-high", 3),
                           ("left_forearm", "left_elbow", "forward-high", 3)])


@pytest.mark.parametrize(("direction", "shares"), [
    ("forward-low", (1 / 3, 2 / 3, 1.0)),  # 60 degrees from where the upper arm rests
    ("forward-middle", (0.0, 1 / 2, 1.0)),  # 21 degrees: it already points that way
])
def test_sizes_turn_a_segment_part_of_the_way_from_neutral(
    baxter: Ecl, direction: str, shares: tuple[float, float, float],
) -> None:
    """A segment's length cannot change: near and mid turn it a third and two thirds of the
    way from its neutral direction toward the one asked, far all the way; a segment already
    pointing that way holds neutral at near and turns half-way at mid, as a stored limb that
    swings does (one rule, ``arcs.swing``)."""
    body = MeasuredBody("baxter")
    body.pose({})
    rest = body.direction(UPPER_ARM)
    d = Direction.parse(direction)
    target = unit(d)
    full = float(degrees(rest, target))
    for size, share in zip((1, 2, 3), shares, strict=True):
        pose = baxter.query("right_upper_arm", "right_shoulder", direction, size)
        got = measured(body, pose.joints, UPPER_ARM)
        want = sized(rest, d, size, (1, 2, 3))
        assert degrees(want, rest) == pytest.approx(share * full, abs=0.5)
        assert degrees(got, want) < 8, size
        assert pose.measured_angle == pytest.approx(float(degrees(got, target)), abs=8), size
    neutral = baxter.query("right_upper_arm", "right_shoulder", "place-middle", 3)
    assert degrees(measured(body, neutral.joints, UPPER_ARM), rest) < 3
    assert neutral.measured_angle is None  # place-middle has no bearing to compare


def test_directions_a_segment_cannot_take_and_toppling_poses_are_refused(nao: Ecl) -> None:
    with pytest.raises(KinesphereError) as err:  # NAO's right upper arm cannot cross left
        nao.query("right_upper_arm", "right_shoulder", "left-middle", 3)
    assert err.value.code == "direction_unavailable"
    assert "limb_11 from distal_11 to distal_12 points" in err.value.message
    with pytest.raises(KinesphereError) as err:  # thigh forward, shin back: no stance holds it
        nao.compound(leg_pair("forward-low", "back-low"))
    assert err.value.code == "direction_unavailable" and "tip the body over" in err.value.message


@pytest.mark.parametrize(("thigh", "shin", "size"), [
    ("forward-middle", "forward-middle", 3),  # a kick forward
    ("right-low", "back-low", 3),
    ("left-forward-low", "forward-middle", 3),  # crossing in front
    ("right-forward-middle", "forward-middle", 2),
])
def test_a_lifted_leg_and_its_shin_stand_on_the_other_leg(
    nao: Ecl, thigh: str, shin: str, size: int,
) -> None:
    """The support rule of stored leg rows at query time: where the lifted leg alone would tip
    the body (measured: the centre of mass less than 1 cm inside the support polygon with the
    other leg at neutral), the other leg carries the body over its foot; the answer stands with
    at least 1 cm to spare and each segment points as the nested solve put it."""
    fk = Fk(platform_model("nao"))
    pose = nao.compound(leg_pair(thigh, shin, size))
    lifted = {j: v for j, v in pose.joints.items() if j in LIFTED}
    stance = {j: v for j, v in pose.joints.items() if j not in LIFTED}
    alone = fk.com_margin(lifted)
    assert alone is not None and alone < 0.01, "the lifted leg alone would stand: no test"
    neutral = load_platform("nao").neutral
    assert max(abs(v - neutral.get(j, 0.0)) for j, v in stance.items()) > 0.01  # it moved
    margin = fk.com_margin(pose.joints)
    assert margin is not None and margin >= 0.01, margin
    body = MeasuredBody("nao")
    body.pose(pose.joints)
    worst = max(float(degrees(body.direction(THIGH), unit(Direction.parse(thigh)))),
                float(degrees(body.direction(SHIN), unit(Direction.parse(shin)))))
    assert pose.measured_angle == pytest.approx(worst, abs=6)


def test_answers_are_deterministic_and_remembered(tmp_path: Path) -> None:
    parts = arm_pair("forward-middle", "left-forward-high")
    first, second = Ecl.open("baxter"), Ecl.open("baxter")
    a = first.compound(parts)
    assert first.compound(parts) == a and first.nested().solves == 1  # remembered
    assert second.compound(parts) == a  # and the same from a fresh start
    plat = load_platform("baxter")
    assert set(a.joints) == set(plat.eurdf.limb_joints("limb_11"))


def test_remembered_solutions_are_bounded_in_bytes_by_what_their_keys_hold() -> None:
    """A key holds the placed joints of the rest of the body: a large brought robot's keys
    cost more, and the byte bound, not only the count, keeps the memory."""
    segment = Segment("limb_11", "distal_11", None, Direction.parse("forward-middle"), 3.0)
    solution = Solution({"a": 0.0}, (1.0,))
    small = solution_bytes(((segment,), ()), solution)
    placed = tuple((f"j{i}", 0.1) for i in range(500))
    large = solution_bytes(((segment,), placed), solution)
    assert large >= small + 500 * ENTRY_BYTES
    assert SOLUTIONS * large > SOLUTION_BYTES  # the count alone would not bound it
    nested = Ecl.open("baxter").nested()
    for i in range(SOLUTIONS):
        nested._solutions.put(((segment,), placed[:-1] + ((f"k{i}", 0.2),)), solution)
    assert nested._solutions.bytes <= SOLUTION_BYTES < SOLUTIONS * large
