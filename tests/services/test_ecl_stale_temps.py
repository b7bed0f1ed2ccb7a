"""A killed ``ecl import`` leaves no temp files behind once the next write runs.

Before: 13 of 16 imports killed mid-write left ``.NAME.xxxx.tmp`` with its ``-wal`` and
``-shm`` beside the databank, forever. Now each writer holds a lock on its temp file, and the
next write removes the temp files whose lock nobody holds (their writer died).
"""

from __future__ import annotations

import fcntl
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from kinesphere.cli import main
from kinesphere.services.ecl.db import remove_stale_temps
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.store import DATA_DIR
from support.paths import ROOT

pytestmark = pytest.mark.processes

KILLED_AT_COMMIT = """
import os, signal, sqlite3, sys
import kinesphere.services.ecl.db as db

class Killed(sqlite3.Connection):
    def execute(self, sql, *args):
        if sql == "COMMIT":  # every row written, nothing committed: the worst moment
            os.kill(os.getpid(), signal.SIGKILL)
        return super().execute(sql, *args)

def connect(path):
    conn = sqlite3.connect(path, isolation_level=None, timeout=10.0, factory=Killed)
    conn.execute("PRAGMA journal_mode=WAL")
    return conn

db.connect = connect
from kinesphere.cli import main
sys.exit(main(sys.argv[1:]))
"""


def leftovers(db: Path) -> list[str]:
    return sorted(p.name for p in db.parent.iterdir() if p.name.startswith(f".{db.name}."))


def test_the_next_import_removes_what_a_killed_one_left(tmp_path: Path) -> None:
    db = Path(shutil.copy(DATA_DIR / "youbot.sqlite", tmp_path / "youbot.sqlite"))
    export = tmp_path / "youbot.json"
    assert main(["ecl", "export", "youbot", "--db", str(db), "-o", str(export)]) == 0
    before = db.read_bytes()
    killed = subprocess.run(
        [sys.executable, "-c", KILLED_AT_COMMIT, "ecl", "import", "youbot", "--db", str(db),
         str(export)], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    left = leftovers(db)
    assert any(n.endswith(".tmp") for n in left) and any(n.endswith("-wal") for n in left)
    assert db.read_bytes() == before  # the databank itself is intact
    assert main(["ecl", "import", "youbot", "--db", str(db), str(export)]) == 0
    assert leftovers(db) == []
    assert Ecl.open("youbot", db).catalogue().sizes


def test_a_live_writers_temp_file_is_left_alone(tmp_path: Path) -> None:
    db = tmp_path / "x.sqlite"
    live, dead = tmp_path / ".x.sqlite.live.tmp", tmp_path / ".x.sqlite.dead.tmp"
    for path in (live, dead, Path(f"{dead}-wal"), Path(f"{dead}-shm"),
                 tmp_path / ".x.sqlite.gone.tmp-wal"):
        path.write_bytes(b"")
    fd = os.open(live, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # as write_tables holds it
        removed = remove_stale_temps(db)
        assert sorted(p.name for p in removed) == [".x.sqlite.dead.tmp",
                                                   ".x.sqlite.gone.tmp-wal"]
        assert leftovers(db) == [".x.sqlite.live.tmp"]
    finally:
        os.close(fd)
