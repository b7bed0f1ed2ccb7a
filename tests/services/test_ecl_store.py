"""The SQLite databank: the paper's schema, constraints, NULL rule, meta, atomic rebuilds."""

import datetime as dt
import json
import os
import shutil
import signal
import sqlite3
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from kinesphere.errors import KinesphereError
from kinesphere.laban import Direction
from kinesphere.platforms.platform import Platform, load_platform
from kinesphere.services.ecl.db import connect, content_digest, quote_ident, read_tables
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.store import PoseRow, write_databank
from kinesphere.services.ecl.vsam import load_vsam
from support.ecl import build, toy_rows
from support.paths import ROOT, TOY


def _sql(path: Path, query: str, args: tuple[object, ...] = ()) -> list[tuple[object, ...]]:
    conn = sqlite3.connect(path)
    try:
        return conn.execute(query, args).fetchall()
    finally:
        conn.close()


def test_schema_is_the_papers(tmp_path: Path) -> None:
    db = tmp_path / "toy.sqlite"
    build(db)
    tables = {r[0] for r in _sql(db, "SELECT name FROM sqlite_master WHERE type = 'table'")}
    assert tables == {"meta", "vsam", "pose", "quality", "support"}
    cols = [(r[1], r[2], r[5]) for r in _sql(db, "PRAGMA table_info(pose)")]
    assert cols == [("p_id", "INTEGER", 1), ("k_id", "INTEGER", 2), ("yaw", "REAL", 0),
                    ("elbow", "REAL", 0), ("wrist", "REAL", 0), ("tail_joint", "REAL", 0)]
    assert [r[1] for r in _sql(db, "PRAGMA table_info(vsam)")] == [
        "k_id", "origin", "limb", "direction"]
    assert _sql(db, "PRAGMA foreign_key_list(pose)")[0][2:5] == ("vsam", "k_id", "k_id")
    assert {r[3] for r in _sql(db, "PRAGMA foreign_key_list(quality)")} == {"p_id", "k_id"}
    assert [r[1] for r in _sql(db, "PRAGMA table_info(quality)")] == [
        "p_id", "k_id", "cosine", "reach", "margin", "tip_x", "tip_y", "tip_z"]
    support = [(r[1], r[2], r[5]) for r in _sql(db, "PRAGMA table_info(support)")]
    assert support == cols  # keyed like pose, a column per joint of P
    assert {r[3] for r in _sql(db, "PRAGMA foreign_key_list(support)")} == {"p_id", "k_id"}
    assert _sql(db, "PRAGMA journal_mode") == [("wal",)]


def test_constraints_are_enforced(tmp_path: Path) -> None:
    db = tmp_path / "toy.sqlite"
    build(db)
    conn = connect(db)
    try:
        with pytest.raises(sqlite3.IntegrityError, match="FOREIGN KEY"):
            conn.execute("INSERT INTO pose (p_id, k_id, yaw) VALUES (1, 9999, 0.0)")
        with pytest.raises(sqlite3.IntegrityError, match="UNIQUE"):
            conn.execute("INSERT INTO pose (p_id, k_id) VALUES (1, 1)")
        with pytest.raises(sqlite3.IntegrityError, match="UNIQUE"):
            conn.execute("INSERT INTO vsam (origin, limb, direction) "
                         "SELECT origin, limb, direction FROM vsam WHERE k_id = 1")
        with pytest.raises(sqlite3.IntegrityError, match="FOREIGN KEY"):
            conn.execute("INSERT INTO quality (p_id, k_id) VALUES (7, 1)")
        with pytest.raises(sqlite3.IntegrityError, match="FOREIGN KEY"):
            conn.execute("DELETE FROM vsam WHERE k_id = 1")
    finally:
        conn.close()


def test_nulls_exactly_where_the_limb_does_not_reach(tmp_path: Path) -> None:
    db = tmp_path / "toy.sqlite"
    plat = load_platform(str(TOY))
    build(db, plat)
    joints = list(plat.joint_names)
    rows = _sql(db, "SELECT v.limb, p.* FROM pose p JOIN vsam v USING (k_id)")
    seen = set()
    for limb, _p, _k, *values in rows:
        assert isinstance(limb, str)
        set_joints = {j for j, v in zip(joints, values, strict=True) if v is not None}
        expected = set() if limb == "c_1" else set(plat.eurdf.limb_joints(limb))
        assert set_joints == expected, limb
        seen.add(limb)
    assert seen == {"limb_11", "limb_12", "limb_21", "c_1"}
    assert set(plat.eurdf.limb_joints("limb_12")) == {"elbow", "wrist"}  # a strict subtree


def test_derived_rows_place_middle_is_neutral_and_core_rows_exist(tmp_path: Path) -> None:
    db = tmp_path / "toy.sqlite"
    build(db)
    pm = _sql(db, "SELECT p.p_id, yaw, elbow, wrist FROM pose p JOIN vsam v USING (k_id) "
                  "WHERE limb = 'limb_11' AND direction = 'place-middle' ORDER BY p_id")
    assert pm == [(1, 0.0, 0.3, 0.0), (2, 0.0, 0.3, 0.0), (3, 0.0, 0.3, 0.0)]
    core = _sql(db, "SELECT direction, count(*) FROM pose p JOIN vsam v USING (k_id) "
                    "WHERE limb = 'c_1' GROUP BY direction")
    assert sorted(core) == sorted((d.slug, 3) for d in Direction.translations())
    # the tail's VSAM has right-middle, place-high, place-low but no rows: no vsam row either
    tail = _sql(db, "SELECT direction FROM vsam WHERE limb = 'limb_21' ORDER BY k_id")
    assert tail == [("place-middle",), ("left-middle",)]
    # quality is kept where given and NULL for derived rows
    q = _sql(db, "SELECT cosine, reach FROM quality JOIN vsam USING (k_id) "
                 "WHERE limb = 'limb_11' AND direction = 'left-high' ORDER BY p_id")
    assert q == [(0.9, 1 / 3), (0.9, 2 / 3), (0.9, 1.0)]


def test_meta_records_platform_hash_vsam_generator_time_and_joints(tmp_path: Path) -> None:
    db = tmp_path / "toy.sqlite"
    plat = load_platform(str(TOY))
    write_databank(db, plat, load_vsam(plat), toy_rows(), "gen-7", {"note": "hand made"})
    meta = {str(key): str(value) for key, value in _sql(db, "SELECT key, value FROM meta")}
    assert meta["platform"] == "toyarm"
    assert meta["eurdf_sha256"] == plat.eurdf.sha256
    assert json.loads(meta["vsam"]) == load_vsam(plat).to_dict()
    assert meta["generator_version"] == "gen-7" and meta["note"] == "hand made"
    assert json.loads(meta["joints"]) == ["yaw", "elbow", "wrist", "tail_joint"]
    created = dt.datetime.fromisoformat(meta["created"])
    assert abs((dt.datetime.now(dt.UTC) - created).total_seconds()) < 600
    with pytest.raises(KinesphereError) as err:
        write_databank(db, plat, load_vsam(plat), toy_rows(), "g", {"created": "x"})
    assert err.value.code == "malformed"


def test_digest_is_deterministic_and_ignores_created_only(tmp_path: Path) -> None:
    a, b = tmp_path / "a.sqlite", tmp_path / "b.sqlite"
    assert build(a) == build(b) == content_digest(a) == content_digest(b)
    conn = sqlite3.connect(b)
    conn.execute("UPDATE meta SET value = '1999-01-01T00:00:00+00:00' WHERE key = 'created'")
    conn.commit()
    assert content_digest(b) == content_digest(a)
    conn.execute("UPDATE pose SET yaw = yaw + 1e-12 WHERE k_id = 1 AND p_id = 1")
    conn.commit()
    conn.close()
    assert content_digest(b) != content_digest(a)
    assert build(b, rows=toy_rows(offset=0.01)) != content_digest(a)


def test_weird_joint_names_are_quoted_safely(tmp_path: Path) -> None:
    folder = tmp_path / "quoted"
    shutil.copytree(TOY, folder)
    eurdf = folder / "toyarm.eurdf"
    weird = 'wr"ist; DROP TABLE pose; --'
    eurdf.write_text(eurdf.read_text().replace('joint name="wrist"',
                                               'joint name="wr&quot;ist; DROP TABLE pose; --"'))
    plat = load_platform(str(folder))
    assert weird in plat.joint_names
    rows = [PoseRow(r.limb, r.origin, r.direction, r.size,
                    {(weird if j == "wrist" else j): v for j, v in r.joints.items()})
            for r in toy_rows()]
    db = tmp_path / "q.sqlite"
    build(db, plat, rows)
    assert quote_ident(weird) == '"wr""ist; DROP TABLE pose; --"'
    t = read_tables(db)
    assert weird in t.joints
    ecl = Ecl.open(plat, db)
    given = next(r for r in rows if r.limb == "forearm" and r.direction == "left-high"
                 and r.size == 3)
    assert ecl.query("limb_12", "distal_12", "left-high", 3).joints == given.joints
    assert ecl.record("limb_12", "distal_12", "left-high", 3, {weird: 0.7}).joints[weird] == 0.7


BAD_ROWS = [
    ("joint outside the limb", PoseRow("limb_12", "distal_12", "left-high", 1,
                                      {"yaw": 0.0, "elbow": 0.0, "wrist": 0.0}), "malformed",
     "yaw"),
    ("missing limb joint", PoseRow("limb_11", "distal_11", "left-high", 1, {"yaw": 0.0}),
     "malformed", "elbow"),
    ("outside limits", PoseRow("limb_12", "distal_12", "left-high", 1,
                               {"elbow": 2.5, "wrist": 0.0}), "malformed", "limits"),
    ("not finite", PoseRow("limb_12", "distal_12", "left-high", 1,
                           {"elbow": float("nan"), "wrist": 0.0}), "malformed", "finite"),
    ("unpaired origin", PoseRow("limb_12", "distal_11", "left-high", 1, {}), "unknown_origin",
     "distal_12"),
    ("unknown limb", PoseRow("leg", "distal_11", "left-high", 1, {}), "unknown_limb", "leg"),
    ("unknown direction", PoseRow("limb_11", "distal_11", "upward", 1, {}), "unknown_direction",
     "upward"),
    ("direction outside the VSAM", PoseRow("tail", "distal_21", "forward-high", 1,
                                           {"tail_joint": 0.1}), "direction_unavailable",
     "forward-high"),
    ("size outside the VSAM", PoseRow("limb_21", "distal_21", "left-middle", 4,
                                      {"tail_joint": 0.1}), "size_out_of_range", "4"),
    ("duplicate row", PoseRow("limb_21", "distal_21", "left-middle", 1, {"tail_joint": 0.1}),
     "conflict", "two rows"),
    ("place-middle not neutral", PoseRow("limb_21", "distal_21", "place-middle", 1,
                                         {"tail_joint": 0.1}), "malformed", "neutral"),
    ("core row with joints", PoseRow("c_1", "c_1", "left-middle", 1, {"yaw": 0.1}),
     "malformed", "core"),
]


@pytest.mark.parametrize(("what", "row", "code", "named"), BAD_ROWS, ids=[b[0] for b in BAD_ROWS])
def test_bad_rows_are_rejected_and_the_old_databank_stays(
    tmp_path: Path, what: str, row: PoseRow, code: str, named: str
) -> None:
    db = tmp_path / "toy.sqlite"
    before = build(db)
    with pytest.raises(KinesphereError) as err:
        build(db, rows=[*toy_rows(offset=0.01), row])
    assert err.value.code == code, err.value.message
    assert named in err.value.message
    assert content_digest(db) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["toy.sqlite"]  # no temp files left


def test_values_within_round_off_of_a_limit_are_clamped(tmp_path: Path) -> None:
    db = tmp_path / "toy.sqlite"
    rows = [*toy_rows()]
    rows[1] = PoseRow("limb_12", "distal_12", rows[1].direction, 1,
                      {"elbow": 2.0 + 1e-12, "wrist": -1.5 - 1e-12})
    build(db, rows=rows)
    got = Ecl.open(str(TOY), db).query("limb_12", "distal_12", rows[1].direction, 1).joints
    assert got == {"elbow": 2.0, "wrist": -1.5}


def test_new_files_are_readable_like_any_other(tmp_path: Path) -> None:
    db = tmp_path / "toy.sqlite"
    build(db)
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(db.stat().st_mode) == 0o666 & ~umask


def test_missing_and_foreign_files_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(KinesphereError) as err:
        read_tables(tmp_path / "none.sqlite")
    assert err.value.code == "unavailable" and "ecl build" in err.value.message
    junk = tmp_path / "junk.sqlite"
    junk.write_bytes(b"not a database at all" * 100)
    with pytest.raises(KinesphereError) as err:
        read_tables(junk)
    assert err.value.code == "malformed"


# The writer child pauses inside its transaction (after the poses, before the quality rows and
# the commit) and says so; the parent kills it there with SIGKILL.
CHILD = r"""
import dataclasses, sys
from kinesphere.platforms.platform import load_platform
from kinesphere.services.ecl import store
from kinesphere.services.ecl.vsam import load_vsam
sys.path.insert(0, sys.argv[3])
from support.ecl import toy_rows

class Pause:
    def __init__(self, rows):
        self.rows = rows
    def __iter__(self):
        yield from self.rows[:5]
        print("MID", flush=True)
        sys.stdin.readline()
        yield from self.rows[5:]

real = store.write_tables
def paused(path, tables):
    return real(path, dataclasses.replace(tables, quality=Pause(list(tables.quality))))
store.write_tables = paused
plat = load_platform(sys.argv[2])
store.write_databank(sys.argv[1], plat, load_vsam(plat), toy_rows(offset=0.25), "new")
print("DONE", flush=True)
"""


def _writer(db: Path) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(db), str(TOY), str(ROOT / "tests")],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "MID"
    return proc


@pytest.mark.processes
def test_a_writer_killed_mid_build_leaves_the_old_databank_serving(tmp_path: Path) -> None:
    db = tmp_path / "toy.sqlite"
    old = build(db)
    before = Ecl.open(str(TOY), db).query("arm", "shoulder", "left-high", 3)
    proc = _writer(db)
    temps = [p for p in tmp_path.iterdir() if p.name.startswith(".toy.sqlite.")]
    assert temps, "the writer is mid-build in a temp file beside the databank"
    os.kill(proc.pid, signal.SIGKILL)
    assert proc.wait() == -signal.SIGKILL
    assert content_digest(db) == old
    ecl = Ecl.open(str(TOY), db)
    assert ecl.query("arm", "shoulder", "left-high", 3) == before
    # control: the same writer, allowed to finish, really replaces the content
    proc = _writer(db)
    out, _ = proc.communicate("\n")
    assert proc.returncode == 0 and out.strip() == "DONE"
    assert content_digest(db) != old
    after = Ecl.open(str(TOY), db).query("arm", "shoulder", "left-high", 3)
    assert after.joints["yaw"] == pytest.approx(before.joints["yaw"] + 0.25)


def hand_rows(plat: Platform, directions: tuple[Direction, ...]) -> list[PoseRow]:
    """Every limb entry of a real platform: neutral plus a small in-limit nudge per size."""
    rows = []
    for entry in load_vsam(plat).entries:
        if entry.is_core:
            continue
        for i, d in enumerate(directions):
            for s in (1, 2, 3):
                joints = {j: plat.eurdf.limits[j].clamp(plat.neutral.get(j, 0.0)
                                                         + 0.02 * s * (i % 3 - 1))
                          for j in plat.eurdf.limb_joints(entry.limb)}
                rows.append(PoseRow(entry.limb, entry.origin, d.slug, s, joints))
    return rows


@pytest.mark.parametrize("name", ["baxter", "nao", "youbot", "packbot", "khepera"])
def test_real_platforms_store_nulls_exactly_outside_each_limb(tmp_path: Path, name: str) -> None:
    plat = load_platform(name)
    db = tmp_path / f"{name}.sqlite"
    rows = hand_rows(plat, (Direction.LEFT_HIGH, Direction.FORWARD_MIDDLE))
    write_databank(db, plat, load_vsam(plat), rows, "hand")
    t = read_tables(db)
    assert t.joints == plat.joint_names
    limb_of = {k: limb for k, _o, limb, _d in t.vsam}
    for _p, k, values in t.pose:
        limb = limb_of[k]
        expected = set() if limb == "c_1" else set(plat.eurdf.limb_joints(limb))
        assert {j for j, v in zip(t.joints, values, strict=True) if v is not None} == expected
    ecl = Ecl.open(plat, db)
    assert {(e.limb, e.origin) for e in ecl.catalogue().limbs} == {
        (p.name, str(p.distal)) for p in plat.eurdf.limbs}
    assert ecl.catalogue().can_translate == plat.base.mobile
    for p in plat.eurdf.limbs:
        pose = ecl.query(p.name, str(p.distal), "left-high", 3)
        assert set(pose.joints) == set(plat.eurdf.limb_joints(p.name))
        if not plat.base.mobile:
            with pytest.raises(KinesphereError) as err:
                ecl.query(p.name, str(p.distal), "left-high", 4)
            assert err.value.code == "cannot_translate"
    if plat.base.mobile:
        step = load_vsam(plat).translation_step
        assert step is not None
        assert ecl.query("c_1", "c_1", "forward", 2).translation == pytest.approx(
            [2 * step, 0.0, 0.0])
