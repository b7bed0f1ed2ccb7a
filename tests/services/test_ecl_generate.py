"""The automated Algorithm 1: determinism, shipped databanks up to date, quality, the paper's
Left-High example, and clean poses (no self-contact, nothing under the floor)."""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest

from kinesphere.cli import main
from kinesphere.laban import Direction
from kinesphere.platforms.mjcf import platform_model
from kinesphere.platforms.platform import load_platform, platform_names
from kinesphere.services.ecl.db import content_digest, read_tables
from kinesphere.services.ecl.generate import COS_FAR, GENERATOR_VERSION, generate
from kinesphere.services.ecl.store import default_db_path
from kinesphere.services.ecl.vsam import load_vsam
from support.ecl import configure, full, origin_of, shipped, tip_world
from support.paths import TOY

SHIPPED = ("baxter", "nao", "youbot", "packbot", "khepera")
CHEAP = ("youbot", "limb_13", "distal_13")  # two joints: the fastest real entry to regenerate


def generated_rows(name: str) -> list[dict[str, Any]]:
    return [r for r in shipped(name).rows() if r["joints"] and r["direction"] != "place-middle"]


def test_generation_is_deterministic() -> None:
    name, limb, origin = CHEAP
    first, report = generate(name, only=(limb, origin))
    second, _ = generate(name, only=(limb, origin))
    assert first and first == second
    assert report.entries[0].kept and report.entries[0].dropped  # a wrist: some, not all
    assert all(round(v, 6) == v for r in first for v in r.joints.values())


def test_every_platform_ships_a_databank() -> None:
    assert set(SHIPPED) <= set(platform_names())
    for name in SHIPPED:
        assert default_db_path(name).is_file(), f"run 'kinesphere ecl build {name}'"


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_databank_matches_current_inputs(name: str) -> None:
    platform = load_platform(name)
    meta = read_tables(default_db_path(name)).meta
    assert meta["eurdf_sha256"] == platform.eurdf.sha256, f"rebuild: {name}.eurdf changed"
    assert meta["vsam"] == load_vsam(platform).to_json(), f"rebuild: {name} vsam.toml changed"
    assert meta["generator_version"] == GENERATOR_VERSION, "rebuild: the generator changed"


def test_regenerating_an_entry_reproduces_the_shipped_rows_exactly() -> None:
    name, limb, origin = CHEAP
    rows, _ = generate(name, only=(limb, origin))
    fresh = {(r.direction, r.size): (r.joints, r.cosine, r.reach, r.margin) for r in rows}
    stored = {(r["direction"], r["size"]): (r["joints"], r["cosine"], r["reach"], r["margin"])
              for r in shipped(name).rows(limb, origin) if r["direction"] != "place-middle"}
    assert fresh == stored


@pytest.mark.parametrize("name", [n for n in SHIPPED if n != "khepera"])
def test_arms_point_where_they_are_told(name: str) -> None:
    rows = generated_rows(name)
    aliases = {p.name: p.alias or "" for p in load_platform(name).eurdf.limbs}
    arms = {r["limb"] for r in rows if aliases[r["limb"]].endswith("arm")}
    assert arms, f"{name} has no arm rows"
    for limb in arms:
        cosines = [r["cosine"] for r in rows if r["limb"] == limb]
        assert statistics.median(cosines) >= 0.9, (name, limb)
    rules, swung = shipped(name).notes("size_rules"), shipped(name).notes("swung")
    for r in rows:  # a reach limb holds its bearing at every size, a swing limb at far
        pair = f"{r['limb']}/{r['origin']}"
        reach = rules[pair] == "reach" and r["direction"] not in swung.get(pair, [])
        if reach or r["size"] == 3:
            assert r["cosine"] >= COS_FAR, r
        assert 0.0 <= r["reach"] <= 1.0 + 1e-6 and r["margin"] >= 0.0, r


@pytest.mark.parametrize("name", SHIPPED)
def test_rows_stay_in_limits_and_null_outside_their_limb(name: str) -> None:
    platform = load_platform(name)
    e = platform.eurdf
    t = read_tables(default_db_path(name))
    cells = {k: (limb, d) for k, _, limb, d in t.vsam}
    for _, k_id, values in t.pose:
        limb, _ = cells[k_id]
        set_joints = {j for j, v in zip(t.joints, values, strict=True) if v is not None}
        expected = set() if limb in e.C else set(e.limb_joints(limb))
        assert set_joints == expected, (limb, k_id)
        for j, v in zip(t.joints, values, strict=True):
            if v is not None:
                assert e.limits[j].lower <= v <= e.limits[j].upper, (j, v)


@pytest.mark.parametrize("name", [n for n in SHIPPED if n != "khepera"])
def test_shipped_poses_touch_nothing_and_reach_further_with_size(name: str) -> None:
    pm = platform_model(name)
    m, e = pm.model, pm.platform.eurdf
    floor = m.geom("floor").id
    robot = [g for g in range(m.ngeom) if m.geom_contype[g] and g != floor]
    fromto = np.zeros(6)
    neutral = configure(pm, {})
    rot = neutral.xmat[m.body(e.root_link).id].reshape(3, 3)
    distances: dict[tuple[str, str, str], list[float]] = {}
    rules, swung = shipped(name).notes("size_rules"), shipped(name).notes("swung")
    for r in generated_rows(name):
        data = configure(pm, full(r))
        mujoco.mj_collision(m, data)
        pairs = [(m.body(m.geom_bodyid[c.geom1]).name, m.body(m.geom_bodyid[c.geom2]).name)
                 for c in data.contact[: data.ncon]]
        assert not pairs, (r["limb"], r["direction"], r["size"], pairs)
        for g in robot:
            if data.geom_xpos[g, 2] < m.geom_rbound[g]:
                assert mujoco.mj_geomDistance(m, data, floor, g, 0.1, fromto) > -1e-3, r
        origin = origin_of(pm, neutral, r["origin"])
        offset = rot.T @ (tip_world(pm, data, r["limb"]) - origin)
        d = np.array(Direction.parse(r["direction"]).vector)
        pair = f"{r['limb']}/{r['origin']}"
        if rules[pair] == "reach" and r["direction"] not in swung.get(pair, []):
            key = (r["limb"], r["origin"], r["direction"])
            distances.setdefault(key, []).append(float(np.linalg.norm(offset)))
        assert offset @ d / np.linalg.norm(offset) == pytest.approx(r["cosine"], abs=1e-5)
    assert distances
    for cell, values in distances.items():  # near, mid, far: the tip gets no closer
        assert all(a <= b + 1e-6 for a, b in zip(values, values[1:], strict=False)), (cell,
                                                                                       values)


@pytest.mark.parametrize("name", ["baxter", "nao", "youbot"])
def test_paper_example_raises_the_right_arm_up_and_to_the_left(name: str) -> None:
    """(limb_11, distal_11, Left-High, 3): the tip ends up and to the left of the shoulder,
    having moved left of, and (from a low neutral) up from, where it rested."""
    pm = platform_model(name)
    e = pm.platform.eurdf
    pose = shipped(name).query("limb_11", "distal_11", "Left-High", 3)
    assert pose.p_id == 3 and set(pose.joints) == set(e.limb_joints("limb_11"))
    neutral, moved = configure(pm, {}), configure(pm, pose.joints)
    rot = neutral.xmat[pm.model.body(e.root_link).id].reshape(3, 3)
    origin = origin_of(pm, neutral, "distal_11")
    rest = rot.T @ (tip_world(pm, neutral, "limb_11") - origin)
    tip = rot.T @ (tip_world(pm, moved, "limb_11") - origin)
    left_high = np.array(Direction.LEFT_HIGH.vector)
    assert tip @ left_high / np.linalg.norm(tip) >= COS_FAR
    assert tip[1] > 0.05 and tip[2] > 0.05, tip  # +y is the robot's left, +z up
    assert tip[1] - rest[1] > 0.05, (rest, tip)  # moved to the left ...
    if rest[2] < 0.5 * np.linalg.norm(tip):  # ... and up, unless it already rested high:
        assert tip[2] - rest[2] > 0.05, (rest, tip)  # youBot's candle neutral is 0.39 m up
    if name == "baxter":  # limb_11 is the right arm: it reaches across the body
        assert tip[1] - rest[1] > 0.3


@pytest.mark.processes  # generation on every core: worker processes
def test_build_and_report_commands(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    db = tmp_path / "toy.sqlite"
    assert main(["ecl", "build", str(TOY), "--db", str(db), "--reasons"]) == 0
    out = capsys.readouterr().out
    assert "rows" in out and "dropped" in out and "limb_21/distal_21" in out
    assert main(["ecl", "report", str(TOY), "--db", str(db), "--rows"]) == 0
    out = capsys.readouterr().out
    assert "medians" in out and "limb_11" in out and "all" in out
    assert main(["ecl", "build", "--all", "--db", str(db)]) == 2
    assert "cannot be used with --all" in capsys.readouterr().err
    # a base-only platform (what --all meets in Khepera) builds its core rows, no limb job
    assert main(["ecl", "build", "khepera", "--db", str(tmp_path / "k.sqlite")]) == 0
    assert "khepera: 0 rows" in capsys.readouterr().out
    assert len(read_tables(tmp_path / "k.sqlite").pose) == len(read_tables(
        default_db_path(load_platform("khepera"))).pose) > 0


@pytest.mark.processes  # generation on every core: worker processes
def test_parallel_build_gives_the_serial_rows(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """Two worker processes, one (limb, origin) pair each: the same rows, quality figures and
    generation report as one process (the content digest covers all but the build time)."""
    one, two = tmp_path / "one.sqlite", tmp_path / "two.sqlite"
    assert main(["ecl", "build", str(TOY), "--db", str(one), "--jobs", "1"]) == 0
    assert main(["ecl", "build", str(TOY), "--db", str(two), "--jobs", "2"]) == 0
    out = capsys.readouterr().out
    assert "wall time with 1 process " in out and "wall time with 2 processes" in out
    assert content_digest(one) == content_digest(two)
    assert read_tables(one).pose and read_tables(one).meta["dropped"] == read_tables(two).meta[
        "dropped"]
    assert main(["ecl", "build", str(TOY), "--db", str(one), "--jobs", "0"]) == 2
