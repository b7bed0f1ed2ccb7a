"""SQLite I/O of the ECL databank: the paper's schema, atomic whole-file writes, full reads.

A build writes a complete new file next to the target in one transaction and ``os.replace``-s
it over the old one, so a crash at any point leaves the previous databank serving. Readers load
everything at once and close the connection, so no long-lived connection ever sees a file
swapped underneath it. Joint columns follow P (eURDF order) and are quoted, so any joint name
is a safe identifier.
"""

from __future__ import annotations

import contextlib
import fcntl
import glob
import hashlib
import json
import math
import os
import sqlite3
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from kinesphere import hints
from kinesphere.errors import KinesphereError

META_KEYS = ("platform", "eurdf_sha256", "vsam", "generator_version", "created", "joints")
QUALITY = ("cosine", "reach", "margin", "tip_x", "tip_y", "tip_z")
"""Per-row measurements: cosine to the direction, fraction of the pull, joint-limit margin,
and where the tip is (tip - origin in the body frame, metres; forward kinematics at build).
A databank written before the tip columns existed reads them as unknown (NULL)."""

Values = tuple[float | None, ...]
Quality = tuple[int, int, float | None, float | None, float | None, float | None,
                float | None, float | None]
"""(p_id, k_id, cosine, reach, margin, tip_x, tip_y, tip_z)"""


@dataclass(frozen=True)
class Tables:
    """The whole content of a databank, as stored (values follow ``joints``)."""

    meta: dict[str, str]
    joints: tuple[str, ...]
    vsam: tuple[tuple[int, str, str, str], ...]  # (k_id, origin, limb, direction)
    pose: tuple[tuple[int, int, Values], ...]  # (p_id, k_id, values)
    quality: tuple[Quality, ...]
    support: tuple[tuple[int, int, Values], ...] = ()  # (p_id, k_id, values): other limbs
    """What the rest of the body does to hold a pose (a stance leg under a lifted one), keyed
    like the pose and NULL for every joint it leaves alone; most poses have none."""

    def digest(self) -> str:
        """SHA-256 of the content; ``created`` is left out so identical builds compare equal."""
        meta = {k: v for k, v in self.meta.items() if k != "created"}
        pose = [(p, k, [canon(v) for v in values]) for p, k, values in self.pose]
        quality = [(p, k, *map(canon, q)) for p, k, *q in self.quality]
        support = [(p, k, [canon(v) for v in values]) for p, k, values in self.support]
        doc = [meta, list(self.joints), self.vsam, pose, quality, support]
        text = json.dumps(doc, sort_keys=True, separators=(",", ":"), allow_nan=False)
        return hashlib.sha256(text.encode("utf-8")).hexdigest()


def canon(v: float | None) -> float | None:
    """SQLite keeps no sign on zero, so -0.0 and 0.0 must hash alike; NaN means unknown."""
    if v is None or not math.isfinite(v):
        return None
    return float(v) + 0.0


def quote_ident(name: str) -> str:
    """A joint name as an SQL identifier: double quotes doubled, so any name is safe."""
    if "\x00" in name:
        raise KinesphereError("malformed", f"joint name {name!r} contains a NUL character")
    return '"' + name.replace('"', '""') + '"'


def _schema(joints: Sequence[str]) -> list[str]:
    lowered = [j.lower() for j in joints]
    clash = sorted({j for j in lowered if lowered.count(j) > 1 or j in ("p_id", "k_id")})
    if clash:
        raise KinesphereError("malformed", f"joint name {clash[0]!r} clashes with another column")
    cols = "".join(f"{quote_ident(j)} REAL, " for j in joints)
    return [
        "CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
        "CREATE TABLE vsam (k_id INTEGER PRIMARY KEY, origin TEXT NOT NULL, limb TEXT NOT NULL, "
        "direction TEXT NOT NULL, UNIQUE (limb, origin, direction))",
        "CREATE TABLE pose (p_id INTEGER NOT NULL, k_id INTEGER NOT NULL REFERENCES vsam (k_id), "
        f"{cols}PRIMARY KEY (p_id, k_id))",
        "CREATE TABLE quality (p_id INTEGER NOT NULL, k_id INTEGER NOT NULL, "
        f"{''.join(f'{q} REAL, ' for q in QUALITY)}PRIMARY KEY (p_id, k_id), "
        "FOREIGN KEY (p_id, k_id) REFERENCES pose (p_id, k_id))",
        f"CREATE TABLE support (p_id INTEGER NOT NULL, k_id INTEGER NOT NULL, {cols}"
        "PRIMARY KEY (p_id, k_id), FOREIGN KEY (p_id, k_id) REFERENCES pose (p_id, k_id))",
    ]


def connect(path: str | Path) -> sqlite3.Connection:
    """A read-write connection in autocommit mode (we BEGIN ourselves), FKs on, WAL."""
    conn = sqlite3.connect(path, isolation_level=None, timeout=10.0)
    conn.execute("PRAGMA foreign_keys=ON")
    conn.execute("PRAGMA journal_mode=WAL")
    return conn


def write_tables(path: str | Path, tables: Tables) -> None:
    """Write ``tables`` to a temp file beside ``path`` in one transaction, then swap it in.

    The writer holds a lock on its temp file (``flock``, released by the kernel when the
    process dies), so the temp files of a writer that was killed are recognised and removed
    by the next write (:func:`remove_stale_temps`), while a live writer's are left alone.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temps(target)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    fcntl.flock(fd, fcntl.LOCK_EX)
    tmp = Path(tmp_name)
    try:
        conn = connect(tmp)
        try:
            conn.execute("BEGIN IMMEDIATE")
            for ddl in _schema(tables.joints):
                conn.execute(ddl)
            conn.executemany("INSERT INTO meta VALUES (?, ?)", sorted(tables.meta.items()))
            conn.executemany("INSERT INTO vsam VALUES (?, ?, ?, ?)", tables.vsam)
            marks = ", ".join("?" * (2 + len(tables.joints)))
            conn.executemany(
                f"INSERT INTO pose VALUES ({marks})", [(p, k, *v) for p, k, v in tables.pose]
            )
            conn.executemany(f"INSERT INTO quality VALUES ({', '.join('?' * (2 + len(QUALITY)))})",
                             tables.quality)
            conn.executemany(
                f"INSERT INTO support VALUES ({marks})", [(p, k, *v) for p, k, v in tables.support]
            )
            conn.execute("COMMIT")
            conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        except BaseException:
            if conn.in_transaction:
                conn.execute("ROLLBACK")
            raise
        finally:
            conn.close()
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, _mode(target))
        if target.exists():
            _settle(target)
        os.replace(tmp, target)
        _fsync_dir(target.parent)
    except sqlite3.Error as exc:
        raise KinesphereError("internal", f"writing {target} failed: {exc}") from exc
    finally:
        _remove_temp(tmp)
        os.close(fd)


def _remove_temp(tmp: Path) -> None:
    for leftover in (tmp, Path(f"{tmp}-wal"), Path(f"{tmp}-shm")):
        with contextlib.suppress(FileNotFoundError):
            leftover.unlink()


def remove_stale_temps(target: Path) -> list[Path]:
    """Remove temp files (and their ``-wal``/``-shm``) that killed writers of ``target``
    left beside it; returns the temp files removed. A temp file whose lock is held belongs
    to a live writer and stays."""
    removed = []
    for tmp in sorted(target.parent.glob(f".{glob.escape(target.name)}.*.tmp")):
        try:
            fd = os.open(tmp, os.O_RDONLY)
        except FileNotFoundError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            continue  # a writer is alive
        else:
            _remove_temp(tmp)
            removed.append(tmp)
        finally:
            os.close(fd)
    for side in target.parent.glob(f".{glob.escape(target.name)}.*.tmp-[ws][ah][lm]"):
        if not Path(str(side)[: -len("-wal")]).exists():  # its temp file is gone
            with contextlib.suppress(FileNotFoundError):
                side.unlink()
                removed.append(side)
    return removed


def _mode(target: Path) -> int:
    """Keep the old file's permissions; a new file gets the usual 0666 & ~umask, not 0600."""
    try:
        return target.stat().st_mode & 0o777
    except FileNotFoundError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _settle(path: Path) -> None:
    """Fold a leftover WAL into the old file so no stale ``-wal`` outlives the swap."""
    with contextlib.suppress(sqlite3.Error):
        conn = sqlite3.connect(path, isolation_level=None, timeout=10.0)
        try:
            conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        finally:
            conn.close()


def _fsync_dir(folder: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _open_read(path: Path) -> sqlite3.Connection:
    """Read-write when possible (so WAL files are cleaned up), else immutable (read-only dirs)."""
    conn = sqlite3.connect(f"file:{path}?mode=rw", uri=True, isolation_level=None)
    try:
        conn.execute("SELECT count(*) FROM sqlite_master").fetchone()
        return conn
    except sqlite3.OperationalError:
        conn.close()
        return sqlite3.connect(f"file:{path}?mode=ro&immutable=1", uri=True, isolation_level=None)


def _built_by(path: Path) -> str:
    """What ``ecl build`` takes to make the databank at ``path``: the brought robot's folder
    it sits in, or the platform it is named after (``data/youbot.sqlite``)."""
    return str(path.parent) if (path.parent / "platform.toml").is_file() else path.stem


def read_tables(path: str | Path) -> Tables:
    """Load a whole databank; a missing or foreign file is a clear error."""
    p = Path(path)
    if not p.is_file():
        raise KinesphereError(
            "unavailable", f"no databank at {p}; build it with '{hints.build_ecl(_built_by(p))}'"
        )
    try:
        conn = _open_read(p)
        try:
            conn.execute("BEGIN")  # one snapshot, even if a record commits meanwhile
            meta = dict(conn.execute("SELECT key, value FROM meta ORDER BY key").fetchall())
            cols = [r[1] for r in conn.execute("PRAGMA table_info(pose)").fetchall()]
            vsam = conn.execute(
                "SELECT k_id, origin, limb, direction FROM vsam ORDER BY k_id"
            ).fetchall()
            pose = conn.execute(
                f"SELECT {', '.join(quote_ident(c) for c in cols)} FROM pose ORDER BY k_id, p_id"
            ).fetchall()
            have = {r[1] for r in conn.execute("PRAGMA table_info(quality)").fetchall()}
            picked = ", ".join(q if q in have else "NULL" for q in QUALITY)
            quality = conn.execute(
                f"SELECT p_id, k_id, {picked} FROM quality ORDER BY k_id, p_id"
            ).fetchall()
            support = []
            if conn.execute("SELECT 1 FROM sqlite_master WHERE name = 'support'").fetchone():
                support = conn.execute(
                    f"SELECT {', '.join(quote_ident(c) for c in cols)} FROM support "
                    "ORDER BY k_id, p_id"
                ).fetchall()
            conn.execute("COMMIT")
        finally:
            conn.close()
    except sqlite3.DatabaseError as exc:
        raise KinesphereError("malformed", f"{p} is not a kinesphere databank ({exc})") from None
    missing = [k for k in META_KEYS if k not in meta]
    if missing or cols[:2] != ["p_id", "k_id"]:
        raise KinesphereError(
            "malformed", f"{p} is not a kinesphere databank (missing {missing or 'pose keys'})"
        )
    joints = tuple(cols[2:])
    if list(joints) != json.loads(meta["joints"]):
        raise KinesphereError("malformed", f"{p}: pose columns do not match meta joints")
    return Tables(
        meta,
        joints,
        tuple((int(k), str(o), str(li), str(d)) for k, o, li, d in vsam),
        tuple((int(r[0]), int(r[1]), tuple(_num(v) for v in r[2:])) for r in pose),
        tuple((int(q[0]), int(q[1]), _num(q[2]), _num(q[3]), _num(q[4]), _num(q[5]),
               _num(q[6]), _num(q[7])) for q in quality),
        tuple((int(r[0]), int(r[1]), tuple(_num(v) for v in r[2:])) for r in support),
    )


def _num(v: object) -> float | None:
    return None if v is None else float(v)  # type: ignore[arg-type]


def content_digest(path: str | Path) -> str:
    """Hash of a databank's content (everything but ``meta.created``) for determinism checks."""
    return read_tables(path).digest()


def upsert_pose(
    path: str | Path,
    joint_order: Sequence[str],
    cell: tuple[str, str, str],
    size: int,
    joints: Mapping[str, float],
) -> None:
    """Store one pose (already validated) in one transaction; its quality becomes unknown and
    any support stored for it is dropped.

    ``cell`` is ``(limb, origin, direction)`` in canonical names; a new cell gets a vsam row.
    """
    limb, origin, direction = cell
    cols = ", ".join(quote_ident(j) for j in joint_order)
    sets = ", ".join(f"{quote_ident(j)} = excluded.{quote_ident(j)}" for j in joint_order)
    marks = ", ".join("?" * (2 + len(joint_order)))
    conn = connect(path)
    try:
        conn.execute("BEGIN IMMEDIATE")
        try:
            found = conn.execute(
                "SELECT k_id FROM vsam WHERE limb = ? AND origin = ? AND direction = ?",
                (limb, origin, direction),
            ).fetchone()
            if found is None:
                cur = conn.execute(
                    "INSERT INTO vsam (origin, limb, direction) VALUES (?, ?, ?)",
                    (origin, limb, direction),
                )
                k_id = int(cur.lastrowid or 0)
            else:
                k_id = int(found[0])
            conn.execute(
                f"INSERT INTO pose (p_id, k_id, {cols}) VALUES ({marks}) "
                f"ON CONFLICT (p_id, k_id) DO UPDATE SET {sets}",
                (size, k_id, *(joints.get(j) for j in joint_order)),
            )
            have = {r[1] for r in conn.execute("PRAGMA table_info(quality)").fetchall()}
            conn.execute(
                "INSERT INTO quality (p_id, k_id) VALUES (?, ?) ON CONFLICT (p_id, k_id) "
                f"DO UPDATE SET {', '.join(f'{q} = NULL' for q in QUALITY if q in have)}",
                (size, k_id),
            )
            # a recorded pose is the super-user's own: no stance is known to hold it
            if conn.execute("SELECT 1 FROM sqlite_master WHERE name = 'support'").fetchone():
                conn.execute("DELETE FROM support WHERE p_id = ? AND k_id = ?", (size, k_id))
            conn.execute("COMMIT")
        except BaseException:
            conn.execute("ROLLBACK")
            raise
    except sqlite3.Error as exc:
        raise KinesphereError("internal", f"recording into {path} failed: {exc}") from exc
    finally:
        conn.close()
