"""The shipped databanks keep what the paper asks and nothing dishonest: NAO's head by gaze,
Baxter's wrists with the paper's three directions, one hip motor on NAO, no pose that topples,
sizes that step from neutral toward the direction without flipping, origins at pivots, and the
coverage tables of docs/ecl.md."""

from __future__ import annotations

import copy
from dataclasses import replace
from functools import cache

import mujoco
import numpy as np
import pytest

from kinesphere.cli import main
from kinesphere.laban import Direction
from kinesphere.platforms.frames import pivot
from kinesphere.platforms.mjcf import platform_model
from kinesphere.platforms.platform import load_platform, platform_names
from kinesphere.services.ecl.balance import MARGIN, Balance, hull, inside
from kinesphere.services.ecl.chains import COS_FAR, DETOUR_SLACK, STEP_SLACK
from kinesphere.services.ecl.coverage import markdown
from kinesphere.services.ecl.db import read_tables
from kinesphere.services.ecl.store import default_db_path
from support.ecl import configure, gaze, origin_of, shipped, tip_world
from support.paths import ROOT

ARTICULATED = ("baxter", "nao", "youbot", "packbot")


@cache
def chains(name: str) -> dict[tuple[str, str, str], list[np.ndarray]]:
    """Every stored cell as (neutral, near, ..., far) joint vectors over its limb's joints."""
    ecl, plat = shipped(name), load_platform(name)
    out: dict[tuple[str, str, str], list[np.ndarray]] = {}
    for r in ecl.rows():
        if not r["joints"] or r["direction"] == "place-middle":
            continue
        key = (r["limb"], r["origin"], r["direction"])
        names = list(r["joints"])
        chain = out.setdefault(key, [np.array([plat.neutral.get(j, 0.0) for j in names])])
        chain.append(np.array([r["joints"][j] for j in names]))
    return out


# -- NAO: one hip motor, the head by gaze, nothing that topples ---------------------------------
def test_nao_hips_share_one_motor() -> None:
    pm = platform_model("nao")
    e, m = pm.platform.eurdf, pm.model
    assert e.mimics["RHipYawPitch"].leader == "LHipYawPitch"
    assert "RHipYawPitch" not in e.joint_names and len(e.joint_names) == 25
    assert "RHipYawPitch" not in pm.actuator_index
    assert m.neq == 1 and m.eq_type[0] == mujoco.mjtEq.mjEQ_JOINT
    data = pm.make_data()  # the physics keeps them together while the left hip moves
    data.ctrl[pm.actuator_index["LHipYawPitch"]] = -0.4
    for _ in range(500):
        mujoco.mj_step(m, data)
    left, right = (data.qpos[pm.qpos_index[j]] for j in ("LHipYawPitch", "RHipYawPitch"))
    assert left == pytest.approx(-0.4, abs=1e-3) and right == pytest.approx(left, abs=1e-4)
    t = read_tables(default_db_path("nao"))
    assert "RHipYawPitch" not in t.joints  # no row can set it on its own
    rows = [r for r in shipped("nao").rows() if r["joints"]]
    assert rows
    for r in rows:
        q = pm.qpos(r["joints"])
        assert q[pm.qpos_index["RHipYawPitch"]] == q[pm.qpos_index["LHipYawPitch"]], r
        if r["limb"] in ("limb_41", "limb_42"):  # a one-leg pose keeps the shared hip still
            assert r["joints"].get("LHipYawPitch", 0.0) == 0.0, r


@pytest.mark.parametrize("name", ARTICULATED)
def test_no_stored_pose_topples(name: str) -> None:
    balance = Balance(platform_model(name))
    pm = platform_model(name)
    for r in shipped(name).rows():
        if r["joints"]:
            margin, bearing = balance.margin(pm.qpos(r["joints"]))
            assert margin >= MARGIN, (r["limb"], r["direction"], r["size"], margin, bearing)


def test_the_balance_check_sees_a_lifted_leg_topple() -> None:
    pm = platform_model("nao")
    balance = Balance(pm)
    margin, bearing = balance.margin(pm.neutral_qpos())
    assert margin > 0.05 and bearing == ("l_ankle", "r_ankle")  # standing on both soles
    lifted = pm.qpos({"LHipPitch": -0.8, "LKneePitch": 0.8})  # left foot up and forward
    margin, bearing = balance.margin(lifted)
    assert bearing == ("r_ankle",) and margin < 0  # the centre of mass is not over the right
    assert "unstable" in (balance.check(lifted) or "")
    square = hull(np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0.5, 0.5]], dtype=float))
    assert len(square) == 4
    assert inside(square, np.array([0.5, 0.5])) == pytest.approx(0.5)
    assert inside(square, np.array([2.0, 0.5])) == pytest.approx(-1.0)
    # a fixed base is bolted down (Baxter's pedestal, a brought arm on a table): never checked
    baxter = platform_model("baxter")
    heavy = replace(baxter, model=copy.deepcopy(baxter.model))
    heavy.model.body_ipos[heavy.model.body("torso").id] = (3.0, 0.0, 0.0)  # torso mass 3 m out
    anchored = Balance(heavy)
    assert anchored.anchored and not balance.anchored
    assert anchored.margin(baxter.neutral_qpos())[0] < 0  # it would fall, were it not bolted
    assert anchored.check(baxter.neutral_qpos()) is None


def test_nao_legs_keep_only_stable_directions_and_the_report_says_why(
    capsys: pytest.CaptureFixture[str],
) -> None:
    unstable = shipped("nao").dropped("unstable")
    assert unstable["limb_31/distal_31"] and unstable["limb_41/distal_41"]
    assert all("unstable" in why for pulls in unstable.values() for why in pulls.values())
    assert main(["ecl", "report", "nao"]) == 0
    out = capsys.readouterr().out
    assert "limb_41/distal_41 dropped for stability:" in out
    assert "forward-middle" in out.split("limb_41/distal_41 dropped for stability:")[1]


def test_nao_head_looks_where_it_is_told() -> None:
    ecl = shipped("nao")
    have = {d.slug for d in ecl.directions("limb_51", "distal_51")}
    assert {"place-middle", "left-middle", "right-middle"} <= have  # the paper's five, ...
    assert not {"place-high", "place-low"} & have  # ... but its neck tilts only 38/30 degrees
    left = gaze("nao", ecl.query("head", "neck", "left-middle", 3).joints)
    right = gaze("nao", ecl.query("head", "neck", "right-middle", 3).joints)
    assert left[1] > 0.95 and right[1] < -0.95
    assert gaze("nao", ecl.query("head", "neck", "place-middle", 3).joints)[0] > 0.99
    up = ecl.query("head", "neck", "place-high", 3)  # served by the nearest: look up
    assert up.direction == "forward-high" and up.substitutions[0].requested == "place-high"
    assert gaze("nao", up.joints)[2] > 0.5
    down = ecl.query("head", "neck", "place-low", 3)
    assert down.direction == "forward-low" and gaze("nao", down.joints)[2] < -0.4


# -- Baxter's wrists: the paper's three per wrist -------------------------------------------------
@pytest.mark.parametrize(("limb", "paper"), [
    ("limb_13", ("left-high", "forward-middle", "right-forward-low")),
    ("limb_23", ("right-high", "forward-middle", "left-forward-low")),
])
def test_baxter_wrists_keep_the_papers_directions(limb: str, paper: tuple[str, ...]) -> None:
    origin = {"limb_13": "distal_13", "limb_23": "distal_23"}[limb]
    for slug in paper:
        rows = shipped("baxter").rows(limb, origin, slug)
        assert [r["size"] for r in rows] == [1, 2, 3], slug
        assert rows[-1]["cosine"] >= COS_FAR


# -- sizes: steps from neutral toward the direction, no flips ----------------------------------
@pytest.mark.parametrize("name", ARTICULATED)
def test_near_is_ahead_of_neutral_and_every_size_further(name: str) -> None:
    pm = platform_model(name)
    e = pm.platform.eurdf
    neutral = configure(pm, {})
    rot = neutral.xmat[pm.model.body(e.root_link).id].reshape(3, 3)
    rows = [r for r in shipped(name).rows() if r["joints"] and r["direction"] != "place-middle"]
    cells: dict[tuple[str, str, str], list[float]] = {}
    for r in rows:
        origin = origin_of(pm, neutral, r["origin"])
        d = np.array(Direction.parse(r["direction"]).vector)
        key = (r["limb"], r["origin"], r["direction"])
        if key not in cells:
            cells[key] = [float(rot.T @ (tip_world(pm, neutral, r["limb"]) - origin) @ d)]
        tip = tip_world(pm, configure(pm, r["joints"]), r["limb"])
        cells[key].append(float(rot.T @ (tip - origin) @ d))
    assert cells
    for key, proj in cells.items():
        assert len(proj) == 4 and all(a < b for a, b in zip(proj, proj[1:], strict=False)), (
            key, proj)


@pytest.mark.parametrize("name", ARTICULATED)
def test_successive_sizes_stay_close_in_joint_space(name: str) -> None:
    for key, chain in chains(name).items():
        q = np.array(chain)
        steps = np.abs(np.diff(q, axis=0))
        turned_back = steps.sum(axis=0) - np.abs(q[-1] - q[0])
        assert turned_back.max() <= DETOUR_SLACK + 1e-9, (key, np.round(q, 3))
        share = np.abs(q[-1] - q[1]) / (len(q) - 2)  # even steps from near to far
        assert (steps[1:] - share).max() <= STEP_SLACK + 1e-9, (key, np.round(q, 3))


# -- origins ---------------------------------------------------------------------------------
def test_origins_are_the_pivots_of_their_joint_groups() -> None:
    pm = platform_model("baxter")
    m, data = pm.model, pm.make_data()
    elbow = pivot(m, data, ("right_e0", "right_e1"))
    assert np.linalg.norm(elbow - data.xanchor[m.joint("right_e1").id]) < 0.05
    assert np.linalg.norm(elbow - data.xanchor[m.joint("right_e0").id]) > 0.2
    nao = platform_model("nao")
    nd = nao.make_data()
    hip = pivot(nao.model, nd, ("LHipYawPitch", "LHipRoll", "LHipPitch"))
    assert np.allclose(hip, nd.xanchor[nao.model.joint("LHipPitch").id], atol=1e-9)
    toy = platform_model(str(ROOT / "tests" / "data" / "toyarm"))  # parallel axes: no pivot
    td = toy.make_data()
    assert np.allclose(pivot(toy.model, td, ("elbow", "wrist")),
                       td.xanchor[toy.model.joint("elbow").id])


# -- coverage --------------------------------------------------------------------------------
def test_the_docs_coverage_tables_are_the_shipped_ones() -> None:
    doc = (ROOT / "docs" / "ecl.md").read_text(encoding="utf-8")
    assert markdown(platform_names()) in doc, "run 'kinesphere ecl coverage' into docs/ecl.md"
