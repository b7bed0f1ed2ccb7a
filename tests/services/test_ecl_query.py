"""f_SB, compound poses, the catalogue and the super-user tools, on real SQLite files."""

import json
import math
import shutil
import timeit
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec
import pytest

from kinesphere.cli import main
from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.platform import load_platform
from kinesphere.protocol import COMPOUND, NO_ID, Pose, SpatialCommand
from kinesphere.services.ecl.db import content_digest
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.store import PoseRow, write_databank
from kinesphere.services.ecl.vsam import load_vsam
from support.ecl import build, toy_rows
from support.paths import TOY


@pytest.fixture
def db(tmp_path: Path) -> Path:
    path = tmp_path / "toy.sqlite"
    build(path)
    return path


@pytest.fixture
def ecl(db: Path) -> Ecl:
    return Ecl.open(str(TOY), db)


def stored(limb: str, d: str, s: int) -> dict[str, float]:
    return next(r.joints for r in toy_rows()
                if r.limb in (limb, {"limb_12": "forearm"}.get(limb)) and r.direction == d
                and r.size == s)


def fixed_toy(tmp_path: Path) -> Ecl:
    """The toy arm bolted down: no translation step, no core entries."""
    folder = tmp_path / "fixed"
    shutil.copytree(TOY, folder)
    cfg = folder / "platform.toml"
    cfg.write_text(cfg.read_text().replace('kind = "omni"', 'kind = "fixed"'))
    vsam = folder / "vsam.toml"
    vsam.write_text(vsam.read_text().replace("translation_step = 0.1", ""))
    plat = load_platform(str(folder))
    write_databank(tmp_path / "fixed.sqlite", plat, load_vsam(plat), toy_rows(), "t")
    return Ecl.open(plat, tmp_path / "fixed.sqlite")


# -- f_SB ------------------------------------------------------------------------------------
def test_integer_size_returns_the_stored_row_with_canonical_names(ecl: Ecl, db: Path) -> None:
    for spelling in ("left-high", "Left High", "LEFT_HIGH", "left  high", Direction.LEFT_HIGH):
        pose = ecl.query("arm", "shoulder", spelling, 2)
        assert (pose.limb, pose.origin, pose.direction) == ("limb_11", "distal_11", "left-high")
        assert pose.joints == stored("limb_11", "left-high", 2)
        assert pose.p_id == 2 and pose.translation is None and pose.size == 2.0
    k_id = [r["k_id"] for r in ecl.rows("limb_11", "distal_11", "left-high")]
    assert pose.k_id == k_id[0] and pose.platform == "toyarm"
    assert ecl.query("limb_11", "distal_11", "left-high", "far").joints == stored(
        "limb_11", "left-high", 3)


def test_fractional_sizes_interpolate_in_joint_space(ecl: Ecl) -> None:
    a, b = stored("limb_11", "left-high", 2), stored("limb_11", "left-high", 3)
    pose = ecl.query("limb_11", "distal_11", "left-high", 2.25)
    assert pose.p_id is None and pose.translation is None
    assert pose.joints == pytest.approx({j: a[j] + 0.25 * (b[j] - a[j]) for j in a})
    assert ecl.query("limb_11", "distal_11", "left-high", "2.25").joints == pose.joints


def test_below_one_blends_from_neutral_and_zero_is_neutral(ecl: Ecl) -> None:
    neutral = {"yaw": 0.0, "elbow": 0.3, "wrist": 0.0}
    near = stored("limb_11", "left-high", 1)
    half = ecl.query("limb_11", "distal_11", "left-high", 0.5)
    assert half.joints == pytest.approx({j: neutral[j] + 0.5 * (near[j] - neutral[j])
                                         for j in near})
    zero = ecl.query("limb_11", "distal_11", "left-high", 0)
    assert zero.joints == neutral and zero.p_id is None


def test_place_middle_is_the_limbs_neutral_pose_at_any_size(ecl: Ecl) -> None:
    pm_k = ecl.rows("limb_12", "distal_12", "place-middle")[0]["k_id"]
    for size in (0, 1, 2.5, 7):
        pose = ecl.query("forearm", "elbow_loc", "place", size)
        assert pose.direction == "place-middle"
        assert pose.joints == {"elbow": 0.3, "wrist": 0.0}
        assert pose.translation is None and pose.k_id == pm_k


def test_beyond_far_keeps_the_far_pose_and_translates_along_the_horizontal(ecl: Ecl) -> None:
    far = stored("limb_11", "left-forward-high", 3)
    pose = ecl.query("limb_11", "distal_11", "left-forward-high", 4.5)
    assert pose.joints == far and pose.p_id is None
    r = 1.5 * 0.1 / math.sqrt(2)  # (s - k_smax) * step * unit horizontal of left-forward
    assert pose.translation == pytest.approx([r, r, 0.0])
    back_low = ecl.query("limb_11", "distal_11", "back-low", 5)
    assert back_low.translation == pytest.approx([-0.2, 0.0, 0.0])  # the level is ignored
    with pytest.raises(KinesphereError) as err:
        ecl.query("limb_11", "distal_11", "place-high", 3.5)
    assert err.value.code == "cannot_translate" and "vertical" in err.value.message


def test_core_entries_translate_only(ecl: Ecl) -> None:
    pose = ecl.query("core", "core", "left", 2)
    assert (pose.limb, pose.origin, pose.direction) == ("c_1", "c_1", "left-middle")
    assert pose.joints == {} and pose.translation == pytest.approx([0.0, 0.2, 0.0])
    assert pose.p_id == 2
    assert ecl.query("c_1", "c_1", "right-back", 1.5).translation == pytest.approx(
        [-0.15 / math.sqrt(2), -0.15 / math.sqrt(2), 0.0])
    with pytest.raises(KinesphereError) as err:
        ecl.query("c_1", "c_1", "left-high", 1)
    assert err.value.code == "direction_unavailable" and "left-middle" in err.value.message


def test_a_fixed_base_cannot_translate(tmp_path: Path) -> None:
    ecl = fixed_toy(tmp_path)
    assert ecl.query("arm", "shoulder", "left-high", 3).joints == stored("limb_11", "left-high", 3)
    for args in (("arm", "shoulder", "left-high", 3.01), ("c_1", "c_1", "left", 1),
                 ("core", "c_1", "forward", 1)):
        with pytest.raises(KinesphereError) as err:
            ecl.query(*args)
        assert err.value.code == "cannot_translate", args
        assert "fixed base" in err.value.message
    cat = ecl.catalogue()
    assert not cat.can_translate and cat.translation_step is None
    assert cat.directions_for_core == []


def test_a_direction_the_limb_lacks_lists_the_ones_it_has(ecl: Ecl) -> None:
    with pytest.raises(KinesphereError) as err:
        ecl.query("tail", "distal_21", "forward", 1)
    assert err.value.code == "direction_unavailable"
    assert err.value.message.endswith("it has: place-middle, left-middle")


BAD_QUERIES = [
    (("leg", "shoulder", "left-high", 1), "unknown_limb", "limb_11 (arm)"),
    ((None, "shoulder", "left-high", 1), "unknown_limb", "NoneType"),
    ((["arm"], "shoulder", "left-high", 1), "unknown_limb", "list"),
    (("arm", "elbow_loc", "left-high", 1), "unknown_origin", "its origins: distal_11"),
    (("arm", "hip", "left-high", 1), "unknown_origin", "distal_11"),
    (("arm", 3, "left-high", 1), "unknown_origin", "int"),
    (("arm", "shoulder", "sideways", 1), "unknown_direction", "sideways"),
    (("arm", "shoulder", 7, 1), "unknown_direction", "int"),
    (("arm", "shoulder", "left-high", float("nan")), "size_out_of_range", "nan"),
    (("arm", "shoulder", "left-high", float("inf")), "size_out_of_range", "inf"),
    (("arm", "shoulder", "left-high", -1), "size_out_of_range", "-1"),
    (("arm", "shoulder", "left-high", -0.5), "size_out_of_range", "-0.5"),
    (("arm", "shoulder", "left-high", "abc"), "size_out_of_range", "abc"),
    (("arm", "shoulder", "left-high", None), "size_out_of_range", "NoneType"),
    (("arm", "shoulder", "left-high", True), "size_out_of_range", "True"),
    (("arm", "shoulder", "left-high", [2]), "size_out_of_range", "list"),
    (("arm", "shoulder", "left-high", 10**400), "size_out_of_range", "large"),
]


@pytest.mark.parametrize(("args", "code", "named"), BAD_QUERIES,
                         ids=[f"{b[1]}-{b[2]}" for b in BAD_QUERIES])
def test_bad_queries_name_the_problem(ecl: Ecl, args: tuple[object, ...], code: str,
                                     named: str) -> None:
    query: Callable[..., object] = ecl.query  # as a caller without types (the wire) calls it
    with pytest.raises(KinesphereError) as err:
        query(*args)
    assert err.value.code == code, err.value.message
    assert named in err.value.message


def test_queries_never_touch_sql(ecl: Ecl, db: Path) -> None:
    expected = ecl.query("arm", "shoulder", "left-high", 2.5)
    db.rename(db.with_suffix(".gone"))
    assert ecl.query("arm", "shoulder", "left-high", 2.5) == expected
    assert ecl.compound([("arm", "shoulder", "left-high", 2.5)]).joints == expected.joints


def test_replies_are_independent_of_the_cache(ecl: Ecl) -> None:
    ecl.query("arm", "shoulder", "left-high", 2).joints["yaw"] = 99.0
    assert ecl.query("arm", "shoulder", "left-high", 2).joints["yaw"] != 99.0


def test_query_cost_is_a_few_microseconds(ecl: Ecl) -> None:
    n = 2000
    best = min(timeit.repeat(lambda: ecl.query("arm", "shoulder", "left-high", 2.5),
                             number=n, repeat=5)) / n
    assert best < 100e-6  # generous: the budget for a 50 Hz loop is 20 ms


# -- compound --------------------------------------------------------------------------------
def test_compound_joins_joints_and_adds_translations(ecl: Ecl) -> None:
    pose = ecl.compound([
        ("arm", "shoulder", "left-high", 1),
        SpatialCommand("tail", "distal_21", "left", 2),
        ("core", "core", "forward", 1),
        ("c_1", "c_1", "left", 2),
    ])
    assert pose.joints == {**stored("limb_11", "left-high", 1), "tail_joint": 1.0}
    assert pose.translation == pytest.approx([0.1, 0.2, 0.0])
    assert (pose.limb, pose.origin, pose.direction, pose.k_id) == (COMPOUND, COMPOUND,
                                                                   COMPOUND, NO_ID)
    assert pose.is_compound and pose.p_id is None
    assert pose.parts[1] == SpatialCommand("limb_21", "distal_21", "left-middle", 2.0)
    assert ecl.compound([("arm", "shoulder", "left-high", 1)]).translation is None


def test_the_same_part_twice_conflicts_unless_last_wins(ecl: Ecl) -> None:
    parts = [("arm", "shoulder", "left-high", 1), ("limb_11", "distal_11", "right-low", 2)]
    with pytest.raises(KinesphereError) as err:
        ecl.compound(parts)
    assert err.value.code == "conflict"
    msg = err.value.message
    assert "part 1 (limb_11, distal_11, left-high, 1)" in msg
    assert "part 2 (limb_11, distal_11, right-low, 2)" in msg
    pose = ecl.compound(parts, last_wins=True)
    assert pose.joints == stored("limb_11", "right-low", 2)
    assert [p.direction for p in pose.parts] == ["right-low"]
    swapped = ecl.compound(parts[::-1], last_wins=True)
    assert swapped.joints == stored("limb_11", "left-high", 1)


def test_compound_rejects_bad_parts(ecl: Ecl) -> None:
    compound: Callable[..., object] = ecl.compound  # as a caller without types calls it
    for parts, code in (([], "malformed"), (["arm"], "malformed"),
                        ([("arm", "shoulder", "left-high")], "malformed"),
                        ([("arm", "shoulder", "left-high", -2)], "size_out_of_range")):
        with pytest.raises(KinesphereError) as err:
            compound(parts)
        assert err.value.code == code


# -- catalogue -------------------------------------------------------------------------------
def test_catalogue_lists_what_can_be_asked(ecl: Ecl) -> None:
    cat = ecl.catalogue()
    assert cat.platform == "toyarm" and cat.core == ["c_1"] and cat.version == ecl.version
    pairs = {(e.limb, e.origin): e for e in cat.limbs}
    assert set(pairs) == {("limb_11", "distal_11"), ("limb_12", "distal_12"),
                          ("limb_21", "distal_21")}
    assert pairs[("limb_11", "distal_11")].directions == [d.slug for d in Direction]
    assert pairs[("limb_21", "distal_21")].directions == ["place-middle", "left-middle"]
    assert pairs[("limb_21", "distal_21")].sizes == [1, 2, 3]
    assert cat.can_translate and cat.translation_step == 0.1
    assert cat.directions_for_core == [d.slug for d in Direction.translations()]
    assert cat.aliases["arm"] == "limb_11" and [j.name for j in cat.joints] == [
        "yaw", "elbow", "wrist", "tail_joint"]
    assert cat.sizes == [1, 2, 3]


# -- record ----------------------------------------------------------------------------------
def test_record_round_trip_bumps_version_and_refreshes_memory(ecl: Ecl, db: Path) -> None:
    v0, before = ecl.version, ecl.query("arm", "shoulder", "left-high", 2)
    pose = ecl.record("arm", "shoulder", "Left High", 2, {"yaw": 0.75})
    assert pose.joints == {**before.joints, "yaw": 0.75}  # unnamed joints keep stored values
    assert ecl.query("limb_11", "distal_11", "left-high", 2) == pose
    assert ecl.query("limb_11", "distal_11", "left-high", 2.5).joints["yaw"] == pytest.approx(
        0.5 * 0.75 + 0.5 * stored("limb_11", "left-high", 3)["yaw"])
    assert ecl.version != v0 and ecl.catalogue().version == ecl.version
    assert content_digest(db).startswith(ecl.version)
    fresh = Ecl.open(str(TOY), db)
    assert fresh.version == ecl.version and fresh.query("arm", "shoulder", "left-high", 2) == pose
    row = fresh.rows("arm", "shoulder", "left-high")[1]
    assert row["cosine"] is None and row["reach"] is None and row["size"] == 2


def test_record_creates_a_cell_the_generator_dropped(ecl: Ecl) -> None:
    with pytest.raises(KinesphereError):
        ecl.query("tail", "distal_21", "right", 1)
    pose = ecl.record("tail", "distal_21", "right", 1, {"tail_joint": -0.4})
    assert pose.joints == {"tail_joint": -0.4} and pose.p_id == 1
    assert ecl.query("tail", "distal_21", "right", 0.5).joints == {"tail_joint": -0.2}
    assert "right-middle" in {e.directions[-1] for e in ecl.catalogue().limbs}
    # a new size past far becomes the new largest stored size for that cell
    ecl.record("tail", "distal_21", "right", 2, {"tail_joint": -0.8})
    assert ecl.query("tail", "distal_21", "right", 2).translation is None


BAD_RECORDS = [
    (("c_1", "c_1", "left", 1, {"yaw": 0.1}), "unknown_limb"),
    (("leg", "shoulder", "left-high", 1, {"yaw": 0.1}), "unknown_limb"),
    ((5, "shoulder", "left-high", 1, {"yaw": 0.1}), "unknown_limb"),
    (("arm", "elbow_loc", "left-high", 1, {"yaw": 0.1}), "unknown_origin"),
    (("arm", "shoulder", "upwards", 1, {"yaw": 0.1}), "unknown_direction"),
    (("tail", "distal_21", "forward-high", 1, {"tail_joint": 0.1}), "direction_unavailable"),
    (("arm", "shoulder", "place-middle", 1, {"yaw": 0.1}), "forbidden"),
    (("arm", "shoulder", "left-high", 0, {"yaw": 0.1}), "size_out_of_range"),
    (("arm", "shoulder", "left-high", 1.5, {"yaw": 0.1}), "size_out_of_range"),
    (("arm", "shoulder", "left-high", -1, {"yaw": 0.1}), "size_out_of_range"),
    (("arm", "shoulder", "left-high", "abc", {"yaw": 0.1}), "size_out_of_range"),
    (("arm", "shoulder", "left-high", float("nan"), {"yaw": 0.1}), "size_out_of_range"),
    (("arm", "shoulder", "left-high", 1, {"tail_joint": 0.1}), "malformed"),
    (("arm", "shoulder", "left-high", 1, {"yaw": 0.1, "knee": 0.0}), "malformed"),
    (("arm", "shoulder", "left-high", 1, {"yaw": 5.0}), "malformed"),
    (("arm", "shoulder", "left-high", 1, {"yaw": "0.1"}), "malformed"),
    (("arm", "shoulder", "left-high", 1, {"yaw": float("inf")}), "malformed"),
    (("arm", "shoulder", "left-high", 1, {}), "malformed"),
    (("arm", "shoulder", "left-high", 1, [("yaw", 0.1)]), "malformed"),
]


@pytest.mark.parametrize(("args", "code"), BAD_RECORDS,
                         ids=[f"{b[1]}-{i}" for i, b in enumerate(BAD_RECORDS)])
def test_bad_records_change_nothing(ecl: Ecl, db: Path, args: tuple[object, ...],
                                    code: str) -> None:
    digest, version = content_digest(db), ecl.version
    record: Callable[..., object] = ecl.record  # as a caller without types (the wire) calls it
    with pytest.raises(KinesphereError) as err:
        record(*args)
    assert err.value.code == code, err.value.message
    assert content_digest(db) == digest and ecl.version == version


# -- rows, export, import --------------------------------------------------------------------
def test_rows_filter_with_aliases(ecl: Ecl) -> None:
    rows = ecl.rows("forearm", "elbow_loc", "Right Low")
    assert [r["size"] for r in rows] == [1, 2, 3]
    assert rows[1]["joints"] == stored("limb_12", "right-low", 2)
    assert len(ecl.rows()) == 26 * 3 * 2 + 3 * 3 + 3 + 8 * 3  # pulls, place-middles, tail, core
    assert {r["limb"] for r in ecl.rows(limb="c_1")} == {"c_1"}


def test_export_import_round_trip_is_byte_identical(ecl: Ecl, tmp_path: Path) -> None:
    ecl.record("arm", "shoulder", "left-high", 2, {"yaw": -0.3})
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    ecl.export_json(first)
    copy = Ecl.from_json(str(TOY), first, tmp_path / "fresh.sqlite")
    copy.export_json(second)
    assert first.read_bytes() == second.read_bytes()
    assert copy.version == ecl.version
    assert copy.query("arm", "shoulder", "left-high", 2) == ecl.query(
        "arm", "shoulder", "left-high", 2)
    doc = json.loads(first.read_text())
    assert doc["format"] == "kinesphere-ecl" and doc["meta"]["platform"] == "toyarm"


def test_import_restores_an_export_over_later_edits(ecl: Ecl, tmp_path: Path) -> None:
    backup = ecl.export_json(tmp_path / "backup.json")
    v0 = ecl.version
    ecl.record("arm", "shoulder", "left-high", 2, {"yaw": -0.3})
    assert ecl.version != v0
    ecl.import_json(backup)
    assert ecl.version == v0
    assert ecl.query("arm", "shoulder", "left-high", 2).joints == stored("limb_11", "left-high", 2)


@pytest.mark.parametrize(("edit", "code"), [
    (lambda d: d["meta"].update(platform="baxter"), "malformed"),
    (lambda d: d["pose"][3]["joints"].update(yaw=9.0), "malformed"),
    (lambda d: d["pose"][3]["joints"].update(tail_joint=0.0), "malformed"),
    (lambda d: d["pose"][3]["joints"].pop("yaw"), "malformed"),
    (lambda d: d["pose"].append(dict(d["pose"][0])), "malformed"),
    (lambda d: d["pose"][0].update(k_id=999), "malformed"),
    (lambda d: d["vsam"][0].update(direction="sideways"), "unknown_direction"),
    (lambda d: d["vsam"][0].update(origin="distal_12"), "unknown_origin"),
    (lambda d: d.update(joints=["yaw"]), "incompatible_version"),
    (lambda d: d.update(format_version=99), "incompatible_version"),
    (lambda d: d.update(format="other"), "malformed"),
])
def test_bad_imports_change_nothing(ecl: Ecl, db: Path, tmp_path: Path,
                                    edit: Callable[[dict[str, Any]], object], code: str) -> None:
    path = ecl.export_json(tmp_path / "x.json")
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))
    digest = content_digest(db)
    with pytest.raises(KinesphereError) as err:
        ecl.import_json(path)
    assert err.value.code == code, err.value.message
    assert content_digest(db) == digest


# -- opening ---------------------------------------------------------------------------------
def test_open_checks_platform_and_finds_the_platform_from_the_databank(tmp_path: Path) -> None:
    plat = load_platform("youbot")
    limb = "limb_13"
    joints = {j: plat.eurdf.limits[j].clamp(plat.neutral.get(j, 0.0) + 0.1)
              for j in plat.eurdf.limb_joints(limb)}
    rows = [PoseRow(limb, "distal_13", "forward-high", s, joints) for s in (1, 2, 3)]
    db = tmp_path / "youbot.sqlite"
    write_databank(db, plat, load_vsam(plat), rows, "t")
    ecl = Ecl.open(db)  # the platform comes from meta
    assert ecl.platform.name == "youbot"
    pose = ecl.query("hand", "distal_13", "forward-high", 3.5)
    assert pose.joints == joints and pose.translation == pytest.approx([0.125, 0.0, 0.0])
    with pytest.raises(KinesphereError) as err:
        Ecl.open("baxter", db)
    assert err.value.code == "malformed" and "youbot" in err.value.message
    with pytest.raises(KinesphereError) as err:
        Ecl.open("baxter", tmp_path / "missing.sqlite")
    assert err.value.code == "unavailable"


# -- CLI -------------------------------------------------------------------------------------
def test_cli_get_record_show_export_import(db: Path, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    base = [str(TOY), "--db", str(db)]
    assert main(["ecl", "get", str(TOY), "arm", "shoulder", "Left High", "2.5", "--json",
                 "--db", str(db)]) == 0
    pose = msgspec.json.decode(capsys.readouterr().out, type=Pose)
    assert pose.limb == "limb_11" and pose.size == 2.5
    assert main(["ecl", "record", *base, "--limb", "arm", "--origin", "shoulder",
                 "--direction", "left-high", "--size", "2", "--joints", "yaw=0.6",
                 "wrist=-0.1"]) == 0
    assert Ecl.open(str(TOY), db).query("arm", "shoulder", "left-high", 2).joints["yaw"] == 0.6
    capsys.readouterr()
    assert main(["ecl", "show", *base, "--limb", "arm", "--direction", "left-high"]) == 0
    out = capsys.readouterr().out
    assert "0.600" in out and "-0.100" in out and "left-high" in out
    out_json = tmp_path / "e.json"
    assert main(["ecl", "export", *base, "-o", str(out_json)]) == 0
    fresh = tmp_path / "fresh.sqlite"
    assert main(["ecl", "import", str(TOY), str(out_json), "--db", str(fresh)]) == 0
    assert content_digest(fresh) == content_digest(db)


@pytest.mark.parametrize(("argv", "message"), [
    (["get", "ARM", "shoulder", "left-high", "1"], "no limb 'ARM'"),
    (["get", "arm", "shoulder", "left-high", "abc"], "'abc'"),
    (["record", "--limb", "arm", "--origin", "shoulder", "--direction", "left-high",
      "--size", "1", "--joints", "yaw"], "NAME=VALUE"),
    (["record", "--limb", "arm", "--origin", "shoulder", "--direction", "left-high",
      "--size", "1", "--joints", "yaw=x"], "not a number"),
    (["record", "--limb", "arm", "--origin", "shoulder", "--direction", "left-high",
      "--size", "1", "--joints", "yaw=1", "yaw=2"], "twice"),
])
def test_cli_errors_exit_2_with_the_reason(db: Path, capsys: pytest.CaptureFixture[str],
                                           argv: list[str], message: str) -> None:
    digest = content_digest(db)
    sub, rest = argv[0], argv[1:]
    assert main(["ecl", sub, str(TOY), "--db", str(db), *rest]) == 2
    assert message in capsys.readouterr().err
    assert content_digest(db) == digest


def test_reload_picks_up_a_rebuild_by_another_writer(ecl: Ecl, db: Path) -> None:
    assert ecl.reload() is False
    build(db, rows=toy_rows(offset=0.1))
    assert ecl.query("arm", "shoulder", "left-high", 3).joints == stored("limb_11", "left-high", 3)
    assert ecl.reload() is True
    assert ecl.query("arm", "shoulder", "left-high", 3).joints["yaw"] == pytest.approx(
        stored("limb_11", "left-high", 3)["yaw"] + 0.1)
