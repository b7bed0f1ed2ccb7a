"""Bring your own robot over every URDF of three public collections installed from PyPI
(example-robot-data, pybullet's pybullet_data with its 1000 random objects, the Robotics
Toolbox's rtb-data): ``platform new`` -> ``describe`` on every file, none left out by name,
and ``ecl build`` on one body of each kind (an arm, a quadruped, a wheeled manipulator, a
humanoid; TIAGo's and Talos's arms, which tests/system/test_byor_e2e.py builds too, are built
once per test run and shared). ``make sweep`` builds every robot and prints the coverage table
(docs/byor.md).

Asserted for every file: no traceback; a file that cannot be imported is refused with one
error line and leaves nothing behind; a platform made is described; every mend is printed and
written into the eURDF; no finger joint is in an arm limb; every legged robot stands with its
feet on the floor. For the sample built: a quadruped's leg keeps at least 8 of the 26 pulls,
a wheeled manipulator's arm at least 12, an arm whose zero pose is singular (an iiwa pointing
up) gets a proposed neutral that keeps at least 18, a humanoid's arm at least 12.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import pytest

from kinesphere.eurdf import load_eurdf
from kinesphere.labeller_names import is_finger_name
from kinesphere.platforms.platform import load_platform
from kinesphere.services.ecl.ik import LIMIT_MARGIN
from support.byor import A1, IIWA, LAIKAGO, TALOS, TIAGO, built_once, standing
from support.sweep import OBJECTS, WRITTEN, Row, kept, made, reason, sweep, urdfs

pytestmark = pytest.mark.processes  # a pool of two worker processes
MIN_PER_LEG = 8
MIN_ARM = 12  # of 26: a wheeled manipulator's arm keeps at least this many
MIN_PROPOSED = 18  # of 26: a stretched 6-7 joint arm's proposed neutral keeps at least this
HUMANOID = TALOS
# One body of each kind, built: (collection, file) -> the word in the alias of the limb to
# build (its first such chain).
SAMPLE = {
    ("pyb", IIWA): "arm",  # an arm whose zero pose points straight up
    ("pyb", A1): "leg",  # a quadruped on a legged base
    ("erd", TIAGO): "arm",  # an arm on a wheeled base
    ("erd", HUMANOID): "arm",  # a humanoid on a legged base
}


# Of the sample, the bodies tests/system/test_byor_e2e.py builds too (the same URDF and arm):
# built once per test run by ``built_once`` (the same commands the sweep runs) and shared;
# the sweep's own folder for each is checked to be the same platform.
BUILT_ONCE = {("erd", TIAGO): "tiago", ("erd", HUMANOID): "talos"}


def _sample(row: Row) -> list[str]:
    word = SAMPLE.get((row["col"], row["rel"]))
    return [n for n, a in row["chains"].items() if word and word in a][:1]


def _built_here(row: Row) -> list[str]:
    return [] if (row["col"], row["rel"]) in BUILT_ONCE else _sample(row)


@pytest.fixture(scope="module")
def swept(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, list[Row]]]:
    parent = tmp_path_factory.mktemp("brought")
    rows = sweep(urdfs(), parent, _built_here)
    found = by_rel(rows)
    limbs = {key: _sample(found[key]) for key in BUILT_ONCE}
    built = built_once(tmp_path_factory, [(name, key[1], found[key]["chains"][limbs[key][0]])
                                          for key, name in BUILT_ONCE.items()])
    for key, name in BUILT_ONCE.items():
        row = found[key]
        row["limbs"] = limbs[key]
        _same_platform(parent / row["name"], built[name])
        row.update(build=0, build_tb=None, kept=kept(built[name], limbs[key]))
    yield parent, rows


def _same_platform(swept: Path, built: Path) -> None:
    """The sweep's folder and the one built once hold the same platform: the same files, the
    same eURDF, platform.toml and vsam.toml but for the name and the folder they mention."""
    def text(folder: Path, file: str) -> str:
        return (folder / file).read_text().replace(str(folder), "<folder>")

    assert sorted(p.relative_to(swept).as_posix() for p in swept.rglob("*")) == sorted(
        p.relative_to(built).as_posix().replace(built.name, swept.name)
        for p in built.rglob("*") if p.suffix != ".sqlite")
    for file in ("{}.eurdf", "platform.toml", "vsam.toml"):
        mine = text(swept, file.format(swept.name)).replace(swept.name, built.name)
        assert mine == text(built, file.format(built.name)), (swept, file)


def by_rel(rows: list[Row]) -> dict[tuple[str, str], Row]:
    return {(r["col"], r["rel"]): r for r in rows}


def test_every_urdf_is_made_or_refused_in_one_line(swept: tuple[Path, list[Row]]) -> None:
    parent, rows = swept
    assert len(rows) > 1150, "fewer URDFs than the three collections hold"
    for r in rows:
        assert r["traceback"] is None, (r["rel"], r["traceback"])
        if r["code"] != 0:
            errors = [ln for ln in r["err"].splitlines() if ln.startswith("error:")]
            assert r["code"] == 2 and len(errors) == 1 and reason(r), (r["rel"], r["err"])
            assert not (parent / r["name"]).exists(), r["rel"]
        else:
            assert r["describe"] == 0 and r["describe_tb"] is None, r["rel"]
    assert not [p for p in parent.iterdir() if p.name.startswith(".")]
    objects = [r for r in rows if r["rel"].startswith(OBJECTS)]
    assert len(objects) == 1000
    assert all(r["code"] == 2 and "nothing to steer" in reason(r) for r in objects)
    assert len(made(rows)) >= 110


def test_every_mend_is_printed_and_written_into_the_eurdf(
    swept: tuple[Path, list[Row]]
) -> None:
    parent, rows = swept
    mended = 0
    for r in made(rows):
        printed = re.findall(r"^  mended: (.*)$", r["out"], re.M)
        written = WRITTEN.findall((parent / r["name"] / f"{r['name']}.eurdf").read_text())
        assert len(printed) == len(written), r["rel"]
        for a, b in zip(printed, written, strict=True):
            assert a.replace("--", "- -").rstrip("-") == b, (r["rel"], a, b)
        mended += bool(printed)
    found = by_rel(rows)
    for key, words in ((("pyb", "xarm/xarm6_robot.urdf"), "balanceinertia"),
                       (("pyb", "laikago/laikago_toes.urdf"), "of size 0) dropped"),
                       (("pyb", "pendulum5.urdf"), "renamed 'world_link'"),
                       (("pyb", "humanoid/humanoid.urdf"), "spherical, read as three revolutes"),
                       (("erd", "double_pendulum_description/urdf/double_pendulum.urdf"),
                        "read as unlimited")):
        assert words in found[key]["out"], (key, found[key]["out"])
    assert mended >= 20


def test_no_finger_moves_with_an_arm(swept: tuple[Path, list[Row]]) -> None:
    parent, rows = swept
    arms = 0
    for r in made(rows):
        e = load_eurdf(parent / r["name"] / f"{r['name']}.eurdf")
        for limb in e.limbs:
            if "arm" in (limb.alias or ""):
                arms += 1
                fingers = [j for j in e.limb_joints(limb.name) if is_finger_name(j)]
                assert not fingers, (r["rel"], limb.alias, fingers)
    assert arms >= 60


def test_every_legged_robot_stands_on_its_feet(swept: tuple[Path, list[Row]]) -> None:
    parent, rows = swept
    legged = [r for r in made(rows) if r["base"] == "legged"]
    assert len(legged) >= 30
    for r in legged:
        low, feet = standing(parent / r["name"])
        assert 0.0 <= low < 0.002 and feet, (r["rel"], low, feet)
    assert "turned so z is up: the file's up axis is y" in by_rel(rows)[("pyb", LAIKAGO)]["out"]


def test_every_neutral_leaves_the_generator_room_from_every_limit(
    swept: tuple[Path, list[Row]]
) -> None:
    """The generator's IK keeps LIMIT_MARGIN from every joint's limits, frozen or not: a
    neutral closer than that (Baxter's fingers, 5 mm into a 21 mm range) leaves it no step."""
    parent, rows = swept
    for r in made(rows):
        plat = load_platform(str(parent / r["name"]))
        neutral = plat.eurdf.with_mimics(plat.neutral)
        for joint, lim in plat.eurdf.limits.items():
            value = neutral.get(joint, 0.0)
            room = min(value - lim.lower, lim.upper - value)
            assert room >= min(LIMIT_MARGIN, (lim.upper - lim.lower) / 2 - 1e-6), (
                r["rel"], joint, value, lim)


def _kept(row: Row) -> int:
    assert row.get("build") == 0 and row.get("build_tb") is None, (row["rel"], row)
    (limb,) = row["limbs"]
    return int(row["kept"][limb])


def test_one_body_of_each_kind_keeps_its_directions(swept: tuple[Path, list[Row]]) -> None:
    _, rows = swept
    found = by_rel(rows)
    iiwa, a1, tiago, talos = (found[key] for key in SAMPLE)
    assert "zero is stretched out, singular" in iiwa["out"]
    assert _kept(iiwa) >= MIN_PROPOSED
    assert a1["base"] == "legged" and _kept(a1) >= MIN_PER_LEG
    assert tiago["base"] in ("diff", "omni") and _kept(tiago) >= MIN_ARM
    assert talos["base"] == "legged" and _kept(talos) >= MIN_ARM
