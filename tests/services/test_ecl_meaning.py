"""The same words mean the same movement: the shipped databanks measured by forward kinematics.

Every figure here is measured from the stored joint values with MuJoCo on the platform's model
(``services.ecl.measure``: tip, origin, bearing, support polygon), never from the generator's
own bookkeeping: sizes are reach (near a bent arm, far stretched out, the bearing held), the
direction a limb rests in is served by itself, a substitution points within 45 degrees of the
request, stability removes sizes and not directions (PackBot's sideways sweep, NAO's legs on
one foot), and ``ecl audit`` prints these figures for every shipped body and a brought one.
"""

from __future__ import annotations

import json
import statistics
from functools import cache
from pathlib import Path

import msgspec
import numpy as np
import pytest

from kinesphere import protocol as pr
from kinesphere.cli import main
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.mjcf import platform_model
from kinesphere.protocol import Pose
from kinesphere.services.ecl.arcs import swing
from kinesphere.services.ecl.measure import Fk, angle_deg, cosine, points_along
from kinesphere.services.ecl.nested import sized
from kinesphere.substitution import MAX_ANGLE_DEG
from support.ecl import full
from support.ecl import shipped as ecl
from support.paths import TOY

ARTICULATED = ("baxter", "nao", "youbot", "packbot")
BENDING_ARMS = [("baxter", "limb_11", "distal_11"), ("baxter", "limb_21", "distal_21"),
                ("nao", "limb_11", "distal_11"), ("nao", "limb_21", "distal_21"),
                ("youbot", "limb_11", "distal_11"), ("packbot", "limb_11", "distal_11")]
ROUNDING = 0.01  # degrees: stored values are rounded to 1e-6


@cache
def fk(name: str) -> Fk:
    return Fk(platform_model(name))


def tips(name: str, limb: str, origin: str) -> dict[str, dict[int, np.ndarray]]:
    """direction -> size -> tip offset from the origin (body frame), measured."""
    out: dict[str, dict[int, np.ndarray]] = {}
    for r in ecl(name).rows(limb, origin):
        if r["direction"] != "place-middle":
            out.setdefault(r["direction"], {})[r["size"]] = fk(name).offset(limb, origin, full(r))
    return out


def pairs(name: str) -> list[tuple[str, str]]:
    return [(e.limb, e.origin) for e in ecl(name).vsam.entries if not e.is_core]


@pytest.mark.parametrize(("name", "limb", "origin"), BENDING_ARMS)
def test_an_arm_that_bends_reaches_near_mid_and_far(name: str, limb: str, origin: str) -> None:
    """Near is a bent arm close to the body, far stretched out, mid in between, and every size
    points its way: the paper's near-, middle- and far-reach."""
    cells = tips(name, limb, origin)
    whole = [c for c in cells.values() if {1, 2, 3} <= set(c)]
    assert len(whole) >= 10, (name, limb, len(whole))
    near = [float(np.linalg.norm(c[1]) / np.linalg.norm(c[3])) for c in whole]
    mid = [float(np.linalg.norm(c[2]) / np.linalg.norm(c[3])) for c in whole]
    assert statistics.median(near) <= 0.7, (name, limb, statistics.median(near))
    assert statistics.median(near) < statistics.median(mid) < 1.0
    for d, c in cells.items():
        for size, offset in c.items():
            assert cosine(offset, np.array(Direction.parse(d).vector)) >= 0.85, (d, size)
    assert ecl(name).notes("size_rules")[f"{limb}/{origin}"] == "reach"


@pytest.mark.parametrize("name", ARTICULATED)
def test_a_part_that_swings_turns_by_the_one_size_rule(name: str) -> None:
    """A limb whose length cannot change (and a leg's pull it swings along) turns its bearing
    size / k_smax of the way from neutral toward far, over the rule the nested solver's
    segments follow too (arcs.swing): each stored near and mid, measured, points where the
    rule says (median within 2 degrees, every one within 15)."""
    e, body = ecl(name), fk(name)
    rules, swung = e.notes("size_rules"), e.notes("swung")
    off: list[float] = []
    for limb, origin in pairs(name):
        key = f"{limb}/{origin}"
        rest = body.neutral_offset(limb, origin)
        for d, cell in tips(name, limb, origin).items():
            if rules[key] != "swing" and d not in swung.get(key, []) or 3 not in cell:
                continue
            unit = np.array(Direction.parse(d).vector) / np.linalg.norm(Direction.parse(d).vector)
            for size in (1, 2):
                if size in cell:
                    want = swing(rest, cell[3], size, (1, 2, 3), points_along(rest, unit))
                    off.append(angle_deg(cell[size], want.offset / np.linalg.norm(want.offset)))
    assert off, name
    assert statistics.median(off) <= 2.0 and max(off) <= 15.0, (name, sorted(off)[-5:])


def test_the_swing_rule_turns_by_size_holds_at_rest_and_goes_over_the_top() -> None:
    """The rule itself (the generator's stored swings and the nested segments call it)."""
    down, forward, up = np.array([0.0, 0, -1]), np.array([1.0, 0, 0]), np.array([0.0, 0, 1])
    for size, share in ((0, 0.0), (1, 1 / 3), (2, 2 / 3), (3, 1.0), (4.5, 1.0)):
        got = swing(down, forward, size, (1, 2, 3), at_rest=False)
        assert got.share == pytest.approx(share)
        assert angle_deg(got.offset, down) == pytest.approx(90 * share, abs=1e-6)
    near, mid = (swing(down, forward, s, (1, 2, 3), at_rest=True) for s in (1, 2))
    assert near.share == 0.0 and angle_deg(near.offset, down) < 1e-6  # rest itself
    assert angle_deg(mid.offset, down) == pytest.approx(45.0)
    over = swing(down, up, 1.5, (1, 2, 3), at_rest=False).offset  # opposite: over the top
    assert angle_deg(over, forward) < 1e-6
    long = swing(2 * down, 4 * forward, 1.5, (1, 2, 3), at_rest=False).offset
    assert np.linalg.norm(long) == pytest.approx(3.0)  # the length is lerped
    # a nested segment resting along the direction asked holds neutral at near, as a limb does
    rest = np.array([0.6, 0.0, -0.8])
    assert np.allclose(sized(rest, Direction.FORWARD_LOW, 1, (1, 2, 3)), rest)
    assert angle_deg(sized(rest, Direction.FORWARD_LOW, 3, (1, 2, 3)),
                     np.array(Direction.FORWARD_LOW.vector)) < 1e-6


@pytest.mark.parametrize("name", ARTICULATED)
def test_the_direction_a_limb_rests_in_is_served_by_itself(name: str) -> None:
    """Asked for the direction it already points in, a limb answers with neutral (near) and
    reaches along it: never a neighbour, never a refusal."""
    for limb, origin in pairs(name):
        rest = fk(name).neutral_directions(limb, origin)
        assert rest, (limb, origin)
        for d in rest:
            for size in (1, 2, 3):
                pose = ecl(name).query(limb, origin, d, size)
                assert pose.direction == d.slug and not pose.substitutions, (limb, d, size)
            near = ecl(name).query(limb, origin, d, 1)
            neutral = ecl(name).query(limb, origin, "place-middle", 1)
            assert all(near.joints[j] == v for j, v in neutral.joints.items()), (limb, d)


@pytest.mark.parametrize("name", ARTICULATED)
def test_every_substitution_points_within_45_degrees_of_the_request(name: str) -> None:
    """Every pull a pair lacks, asked at every size as a fleet command: what is served points
    (measured) within 45 degrees of what was asked, or the answer is direction_unavailable;
    the answer's measured_angle says how far."""
    served = 0
    for limb, origin in pairs(name):
        have = {d.slug for d in ecl(name).directions(limb, origin)}
        for d in Direction.pulls():
            if d.slug in have:
                continue
            for size in (1, 2, 3):
                try:
                    pose = ecl(name).query(limb, origin, d, size)
                except KinesphereError as exc:
                    assert exc.code == "direction_unavailable"
                    continue
                served += 1
                angle = angle_deg(fk(name).offset(limb, origin, pose.joints), np.array(d.vector))
                assert angle <= MAX_ANGLE_DEG + ROUNDING, (limb, d, size, pose.direction, angle)
                assert pose.substitutions and pose.measured_angle is not None
                assert pose.measured_angle == pytest.approx(angle, abs=0.05)
    assert served > 0


def test_packbot_sweeps_low_to_its_side_without_substitution() -> None:
    """The motivating task: the arm held low to the side while the base drives forward. Left-
    middle and left-low are stored (near and mid at least), and the gamepad's sweep (left-low
    at far, what LT and the stick send) is answered exactly, by a pose that points left-low."""
    pb = ecl("packbot")
    for d in ("left-middle", "left-low", "right-middle", "right-low"):
        for size in (1, 2):
            pose = pb.query("arm", "shoulder", d, size, exact=True)
            assert pose.p_id == size and not pose.substitutions, (d, size)
            offset = fk("packbot").offset("limb_11", "distal_11", pose.joints)
            assert cosine(offset, np.array(Direction.parse(d).vector)) >= 0.85, (d, size)
    sweep = pb.query("limb_11", "distal_11", Direction.LEFT_LOW, 3)
    assert sweep.direction == "left-low" and not sweep.substitutions
    assert sweep.translation is None  # the arm reaches; the drive is the stick's
    left_low = [e for e in pb.catalogue().limbs if e.limb == "limb_11"][0]
    assert "left-low" in left_low.directions and "left-middle" in left_low.directions
    margins = [fk("packbot").com_margin(r["joints"]) for r in pb.rows("limb_11", "distal_11",
                                                                        "left-low")]
    assert min(m for m in margins if m is not None) >= 0.01


def test_packbot_masses_follow_the_published_envelope() -> None:
    m = platform_model("packbot").model
    mass = {m.body(b).name: float(m.body_mass[b]) for b in range(m.nbody)}
    base = sum(mass[b] for b in ("base_link", "left_track", "right_track", "flippers"))
    assert base == pytest.approx(19.0, abs=0.5) and sum(mass.values()) == pytest.approx(31.0,
                                                                                        abs=0.5)


@pytest.mark.parametrize(("limb", "origin"), [("limb_31", "distal_31"), ("limb_41", "distal_41")])
def test_nao_stands_on_one_leg_while_the_other_gestures(limb: str, origin: str) -> None:
    """Each leg keeps at least 12 directions at near or mid: the stance leg carries the body
    over its foot (the rows' support), as a person shifts their weight."""
    cells = tips("nao", limb, origin)
    assert len([c for c in cells.values() if {1, 2} & set(c)]) >= 12, sorted(cells)
    lifted = [r for r in ecl("nao").rows(limb, origin) if r["support"]]
    assert lifted, "a lifted leg is held by the other one"
    stance = {"limb_31": "L", "limb_41": "R"}[limb]
    assert all(j.startswith(stance) for r in lifted for j in r["support"])
    home = ecl("nao").query(limb, origin, "place-middle", 1).joints  # both legs stand again
    held = {j for r in lifted for j in r["support"]}
    neutral = platform_model("nao").platform.neutral
    assert held <= set(home) and all(home[j] == neutral.get(j, 0.0) for j in held)


@pytest.mark.parametrize("name", ["nao", "youbot", "packbot"])  # Baxter is bolted down
def test_every_stored_row_stands_with_a_centimetre_to_spare(name: str) -> None:
    body = fk(name)
    assert not body.anchored
    for r in ecl(name).rows():
        if r["joints"]:
            margin = body.com_margin(full(r))
            assert margin is None or margin >= 0.01, (r["limb"], r["direction"], r["size"],
                                                      margin)


def test_answers_carry_the_measured_angle_and_old_peers_keep_working() -> None:
    pose = ecl("baxter").query("right_arm", "right_shoulder", "left-high", 3)
    offset = fk("baxter").offset("limb_11", "distal_11", pose.joints)
    measured = angle_deg(offset, np.array(Direction.LEFT_HIGH.vector))
    assert pose.measured_angle == pytest.approx(measured, abs=0.01)
    assert ecl("baxter").query("right_arm", "right_shoulder", "place-middle", 3
                               ).measured_angle is None
    wire = pr.encode(pose)
    old = msgspec.to_builtins(pose)
    del old["measured_angle"]  # an answer from an older databank
    decoded = pr.decode(msgspec.msgpack.encode(old), Pose)
    assert decoded.measured_angle is None and decoded.joints == pose.joints

    class OldPose(msgspec.Struct):  # a peer's Pose from before the field (unknowns ignored)
        platform: str
        joints: dict[str, float]

    assert msgspec.msgpack.decode(wire, type=OldPose).joints == pose.joints  # a peer without it


def test_audit_prints_the_figures_for_every_shipped_body_and_a_brought_one(
    tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    for name in (*ARTICULATED, "khepera"):
        assert main(["ecl", "audit", name]) == 0
        out = capsys.readouterr().out
        if name == "khepera":
            assert "no limbs" in out
            continue
        for head in ("rule", "cosine min/p5/med", "size/far", "substituted", "neutral",
                     "min margin"):
            assert head in out, (name, head)
        assert main(["ecl", "audit", name, "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        assert doc["platform"] == name and len(doc["pairs"]) == len(pairs(name))
        arm = doc["pairs"][0]
        assert arm["cosine_min"] >= 0.85 and arm["fraction"]["1"] <= 0.7
        assert all(s["angle"] <= MAX_ANGLE_DEG + ROUNDING for p in doc["pairs"]
                   for s in p["substituted"])
        assert all(how == "stored" for p in doc["pairs"] for how in p["neutral"].values())
    db = tmp_path / "toy.sqlite"
    assert main(["ecl", "build", str(TOY), "--db", str(db)]) == 0
    capsys.readouterr()
    assert main(["ecl", "audit", str(TOY), "--db", str(db), "--json"]) == 0
    toy = json.loads(capsys.readouterr().out)
    assert toy["platform"] == "toyarm" and toy["pairs"] and toy["generator"]
    assert all(p["rule"] in ("reach", "swing") for p in toy["pairs"])
    assert main(["ecl", "audit", str(TOY), "--db", str(db)]) == 0
    assert "toyarm audit" in capsys.readouterr().out
