"""The shipped databanks keep what the paper asks and nothing dishonest: NAO's head by gaze,
Baxter's wrists with the paper's three directions, one hip motor on NAO, no pose that topples,
sizes that grow by the limb's rule without flipping, origins at pivots, and the coverage
tables of docs/ecl.md."""

from __future__ import annotations

import copy
from dataclasses import replace
from functools import cache

import mujoco
import numpy as np
import pytest

from kinesphere.cli import main
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.frames import pivot
from kinesphere.platforms.mjcf import platform_model
from kinesphere.platforms.platform import load_platform, platform_names
from kinesphere.services.ecl.balance import MARGIN, Balance, hull, inside
from kinesphere.services.ecl.chains import COS_FAR, DETOUR_SLACK, STEP_SLACK
from kinesphere.services.ecl.coverage import markdown
from kinesphere.services.ecl.db import read_tables
from kinesphere.services.ecl.store import default_db_path
from support.ecl import configure, full, gaze, origin_of, shipped, tip_world
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
            margin, bearing = balance.margin(pm.qpos(full(r)))
            assert margin >= MARGIN, (r["limb"], r["direction"], r["size"], margin, bearing)


def test_the_balance_check_sees_a_lifted_leg_topple() -> None:
    pm = platform_model("nao")
    balance = Balance(pm)
    margin, bearing = balance.margin(pm.neutral_qpos())
    assert margin > 0.05 and bearing == ("l_ankle", "r_ankle")  # standing on both soles
    lifted = pm.qpos({"LHipPitch": -0.8, "LKneePitch": 1.4})  # left knee up, the foot lifted
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


def test_nao_legs_lose_sizes_not_directions_and_the_report_says_so(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """With the stance leg carrying the body, no leg direction is dropped for stability; where
    the largest sizes would still topple, only they go, and ``ecl report`` names them."""
    unstable, short = shipped("nao").dropped("unstable"), shipped("nao").dropped("short")
    for pair in ("limb_31/distal_31", "limb_41/distal_41"):
        assert not unstable[pair] and short[pair], pair
        assert all(why.startswith("size ") and "unstable" in why for why in short[pair].values())
    assert main(["ecl", "report", "nao"]) == 0
    out = capsys.readouterr().out
    assert "size rule" in out and "reach" in out and "swing" in out
    assert "limb_41/distal_41 sizes removed for stability:" in out


def test_nao_head_looks_where_it_is_told() -> None:
    ecl = shipped("nao")
    have = {d.slug for d in ecl.directions("limb_51", "distal_51")}
    assert {"place-middle", "left-middle", "right-middle"} <= have  # the paper's five, ...
    assert "forward-middle" in have  # where it looks at rest: answered by itself
    assert not {"place-high", "place-low"} & have  # ... but its neck tilts only 38/30 degrees
    left = gaze("nao", ecl.query("head", "neck", "left-middle", 3).joints)
    right = gaze("nao", ecl.query("head", "neck", "right-middle", 3).joints)
    assert left[1] > 0.95 and right[1] < -0.95
    assert gaze("nao", ecl.query("head", "neck", "place-middle", 3).joints)[0] > 0.99
    ahead = ecl.query("head", "neck", "forward-middle", 1)
    assert not ahead.substitutions and gaze("nao", ahead.joints)[0] > 0.99
    for slug in ("place-high", "place-low"):  # the nearest pose looks 51/60 degrees away:
        with pytest.raises(KinesphereError) as err:  # not a substitute
            ecl.query("head", "neck", slug, 3)
        assert err.value.code == "direction_unavailable"
    up = ecl.query("head", "neck", "forward-high", 3)
    assert gaze("nao", up.joints)[2] > 0.5


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


# -- sizes: grow by the limb's rule, no flips --------------------------------------------------
@pytest.mark.parametrize("name", ARTICULATED)
def test_sizes_grow_by_the_limbs_rule(name: str) -> None:
    """Reach: the tip gets no closer to the origin from near to far; swing: the bearing turns
    no further from the direction (a cell holding neutral at every size does neither)."""
    pm = platform_model(name)
    e = pm.platform.eurdf
    neutral = configure(pm, {})
    rot = neutral.xmat[pm.model.body(e.root_link).id].reshape(3, 3)
    rules, swung = shipped(name).notes("size_rules"), shipped(name).notes("swung")
    rows = [r for r in shipped(name).rows() if r["joints"] and r["direction"] != "place-middle"]
    cells: dict[tuple[str, str, str], list[np.ndarray]] = {}
    for r in rows:
        at = origin_of(pm, neutral, r["origin"])
        tip = tip_world(pm, configure(pm, full(r)), r["limb"])
        cells.setdefault((r["limb"], r["origin"], r["direction"]), []).append(rot.T @ (tip - at))
    assert cells
    for (limb, origin, slug), tips in cells.items():
        pair = f"{limb}/{origin}"
        d = np.array(Direction.parse(slug).vector)
        if rules[pair] == "reach" and slug not in swung.get(pair, []):
            grows = [float(np.linalg.norm(t)) for t in tips]
        else:
            grows = [float(t @ d / np.linalg.norm(t)) for t in tips]
        assert all(a <= b + 1e-6 for a, b in zip(grows, grows[1:], strict=False)), (
            limb, slug, grows)


@pytest.mark.parametrize("name", ARTICULATED)
def test_successive_sizes_stay_close_in_joint_space(name: str) -> None:
    for key, chain in chains(name).items():
        q = np.array(chain[1:])  # near .. far: near may fold further than neutral
        if len(q) < 2:
            continue
        steps = np.abs(np.diff(q, axis=0))
        turned_back = steps.sum(axis=0) - np.abs(q[-1] - q[0])
        assert turned_back.max() <= DETOUR_SLACK + 1e-9, (key, np.round(q, 3))
        share = np.abs(q[-1] - q[0]) / (len(q) - 1)  # even steps from near to far
        assert (steps - share).max() <= STEP_SLACK + 1e-9, (key, np.round(q, 3))


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
