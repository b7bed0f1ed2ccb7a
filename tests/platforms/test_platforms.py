"""The five platforms: the paper's label sets, real joint limits, stable MuJoCo models."""

import csv
import math

import mujoco
import numpy as np
import pytest
import yourdfpy

from kinesphere.platforms.mjcf import BASE_JOINTS, platform_model
from kinesphere.platforms.platform import load_platform, platform_names
from support.paths import REFERENCE

PLATFORMS = ["baxter", "khepera", "nao", "packbot", "youbot"]


def test_the_five_platforms_ship() -> None:
    assert platform_names() == PLATFORMS


def _labels(prefix: str, pairs: str) -> set[str]:
    return {f"{prefix}_{p}" for p in pairs.split()}


PAPER_SETS = {
    "baxter": (
        {"c_1"},
        _labels("distal", "11 12 13 21 22 23"),
        _labels("limb", "11 12 13 21 22 23"),
    ),
    "nao": (
        {"c_1"},
        _labels("distal", "11 21 31 41 51 12 22 32 42"),
        _labels("limb", "11 21 31 41 51 12 22 32 42"),
    ),
    "youbot": ({"c_1"}, _labels("distal", "11 12 13"), _labels("limb", "11 12 13")),
    "khepera": ({"c_1"}, set(), set()),
}


@pytest.mark.parametrize("name", sorted(PAPER_SETS))
def test_label_sets_reproduce_the_paper(name: str) -> None:
    e = load_platform(name).eurdf
    c, j, lb = PAPER_SETS[name]
    assert (set(e.C), set(e.J), set(e.L)) == (c, j, lb)


@pytest.mark.parametrize(("name", "dof"), [("baxter", 14), ("nao", 25), ("youbot", 5)])
def test_dof_counts(name: str, dof: int) -> None:
    assert len(load_platform(name).eurdf.P) == dof


def test_humanoid_conventions() -> None:
    baxter, nao = load_platform("baxter").eurdf, load_platform("nao").eurdf
    assert all(j.startswith("right_") for j in baxter.limb_joints("limb_11"))
    assert all(j.startswith("left_") for j in baxter.limb_joints("limb_21"))
    assert nao.limb_joints("limb_12")[0] == "RElbowYaw"  # the paper: limb_12 = right forearm
    assert nao.limb_joints("limb_51") == ("HeadYaw", "HeadPitch")
    assert all(j.startswith("RHip") or j.startswith("R") for j in nao.limb_joints("limb_31"))
    assert all(j.startswith("L") for j in nao.limb_joints("limb_41"))
    # links carry several labels
    tip = baxter.tip_link("limb_13")
    assert {"limb_11", "limb_12", "limb_13"} <= set(baxter.labels_of_link(tip))


def test_packbot_has_an_arm_and_flippers_on_a_skid_base() -> None:
    p = load_platform("packbot")
    assert p.base.kind == "skid"
    assert {"limb_11", "limb_21"} <= set(p.eurdf.L)
    assert len(p.eurdf.limb_joints("limb_11")) >= 6


@pytest.mark.parametrize("name", PLATFORMS)
def test_loads_in_yourdfpy(name: str) -> None:
    path = load_platform(name).eurdf.path
    assert path is not None
    urdf = yourdfpy.URDF.load(str(path), load_meshes=False, build_scene_graph=True)
    assert len(urdf.actuated_joints) == len(load_platform(name).eurdf.P)


@pytest.mark.parametrize("name", PLATFORMS)
def test_mujoco_model_steps_one_second_stably_without_contacts(name: str) -> None:
    pm = platform_model(name)
    model, data = pm.model, pm.make_data()
    assert data.ncon == 0
    q0 = data.qpos.copy()
    for _ in range(int(1.0 / model.opt.timestep)):
        mujoco.mj_step(model, data)
        assert data.ncon == 0
    assert np.all(np.isfinite(data.qpos))
    assert np.max(np.abs(data.qpos - q0)) < 1e-2
    assert set(pm.actuator_index) >= set(pm.platform.joint_names)


@pytest.mark.parametrize("name", PLATFORMS)
def test_mobile_bases_can_be_driven(name: str) -> None:
    pm = platform_model(name)
    mobile = pm.platform.base.mobile
    assert (
        set(BASE_JOINTS) <= set(pm.qpos_index)
        if mobile
        else not set(BASE_JOINTS) & set(pm.qpos_index)
    )
    if not mobile:
        return
    model, data = pm.model, pm.make_data()
    data.ctrl[pm.actuator_index["base_x"]] = 0.2
    data.ctrl[pm.actuator_index["base_yaw"]] = 0.5
    for _ in range(1000):
        mujoco.mj_step(model, data)
    assert data.qpos[pm.qpos_index["base_x"]] == pytest.approx(0.2, abs=0.01)
    assert data.qpos[pm.qpos_index["base_yaw"]] == pytest.approx(0.5, abs=0.01)


def _reference_limits(table: str) -> dict[str, tuple[float, float]]:
    path = REFERENCE / table
    assert path.is_file(), f"reference table missing: {path} (shared/ must sit beside the repo)"
    with open(path, newline="") as fh:
        return {
            row["joint"]: (float(row["lower"]), float(row["upper"]))
            for row in csv.DictReader(fh)
            if row["type"] in ("revolute", "prismatic") and row["lower"]
        }


@pytest.mark.parametrize(
    ("name", "table"),
    [("baxter", "baxter_joints.csv"), ("nao", "nao_joints.csv"), ("youbot", "youbot_joints.csv")],
)
def test_mujoco_joint_limits_equal_the_reference_tables(name: str, table: str) -> None:
    pm = platform_model(name)
    reference = _reference_limits(table)
    for joint in pm.platform.joint_names:
        assert joint in reference, f"{joint} is not in {table}"
        jid = pm.model.joint(joint).id
        assert pm.model.jnt_limited[jid]
        lo, hi = pm.model.jnt_range[jid]
        assert math.isclose(lo, reference[joint][0], abs_tol=1e-6), joint
        assert math.isclose(hi, reference[joint][1], abs_tol=1e-6), joint


@pytest.mark.parametrize("name", PLATFORMS)
def test_neutral_pose_is_inside_limits(name: str) -> None:
    p = load_platform(name)
    for joint, value in zip(p.joint_names, p.neutral_vector(), strict=True):
        lim = p.eurdf.limits[joint]
        assert lim.lower <= value <= lim.upper


def test_joint_limits_hold_when_the_arms_push_into_each_other() -> None:
    """Both Baxter arms swung inward at full stretch collide; no joint leaves its range."""
    pm = platform_model("baxter")
    model, data = pm.model, pm.make_data()
    # shoulders swung fully inward (0.01 rad inside the limit, as the agent clamps), arms straight
    targets = {"right_s0": 1.6917, "left_s0": -1.6917, "right_s1": 0.0, "left_s1": 0.0,
               "right_e1": 0.0, "left_e1": 0.0, "right_w1": 0.0, "left_w1": 0.0}
    for joint, value in targets.items():
        data.ctrl[pm.actuator_index[joint]] = value
    touched, worst = False, 0.0
    for _ in range(1500):
        mujoco.mj_step(model, data)
        touched |= data.ncon > 0
        for joint in pm.platform.joint_names:
            jid = model.joint(joint).id
            q = data.qpos[model.jnt_qposadr[jid]]
            lo, hi = model.jnt_range[jid]
            worst = max(worst, lo - q, q - hi)
    assert touched, "the arms were meant to collide"
    assert worst < 0.01  # the agent keeps targets 0.01 rad inside the limits


@pytest.mark.parametrize("name", PLATFORMS)
def test_the_model_a_robot_steps_moves_as_the_full_model_bit_for_bit(name: str) -> None:
    """The agent's model leaves out the visual geometry (a camera's only): every joint, limit,
    gain, collision geom and exclusion stays, and the same servo targets give the same motion
    to the last bit, contacts included (Baxter's arms swung into each other)."""
    full, lean = platform_model(name), platform_model(name, visuals=False)
    fm, lm = full.model, lean.model
    assert not any(lm.geom_group == 1) and any(fm.geom_group == 1)  # the visual geoms go

    def collision_geoms(m: mujoco.MjModel) -> list[str]:
        return [m.geom(i).name for i in range(m.ngeom) if m.geom_contype[i] or
                m.geom_conaffinity[i]]

    assert collision_geoms(lm) == collision_geoms(fm)
    assert lean.excluded_pairs == full.excluded_pairs
    assert (lean.qpos_index, lean.dof_index, lean.actuator_index) == \
        (full.qpos_index, full.dof_index, full.actuator_index)
    for field in ("jnt_range", "actuator_gainprm", "actuator_biasprm", "body_mass",
                  "body_inertia", "dof_damping", "dof_armature"):
        assert np.array_equal(getattr(lm, field), getattr(fm, field)), field
    fd, ld = full.make_data(), lean.make_data()
    rng = np.random.default_rng(7)
    acts = [full.actuator_index[j] for j in full.platform.joint_names]
    ranges = fm.jnt_range[[fm.joint(j).id for j in full.platform.joint_names]]
    lo, hi = np.where(ranges[:, 0] < ranges[:, 1], ranges.T, [[-1.0], [1.0]])  # continuous
    contacts = 0
    for k in range(1500):
        if k % 250 == 0:  # a new target for every joint, anywhere in its range
            target = rng.uniform(lo, hi) if k else \
                np.where(np.arange(len(acts)) % 2 == 0, lo + 0.01, hi - 0.01)
            fd.ctrl[acts] = ld.ctrl[acts] = target
        mujoco.mj_step(fm, fd)
        mujoco.mj_step(lm, ld)
        contacts += fd.ncon
        assert fd.ncon == ld.ncon
        assert np.array_equal(fd.qpos, ld.qpos) and np.array_equal(fd.qvel, ld.qvel), k
    if name == "baxter":
        assert contacts > 0, "the targets were meant to bring limbs into contact"
