"""``ecl record --from-robot``: the super-user moves a running robot, then records its pose."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from kinesphere.cli import main
from kinesphere.services.ecl.ecl import Ecl
from kinesphere.services.ecl.store import default_db_path
from support.agents import CommandSender, DatabankProcess, running_agent  # noqa: F401
from support.network import Hub

LIMB = ("limb_11", "distal_11", "forward-middle", 2)


def test_record_captures_the_running_robots_limb(
    hub: Hub, databank: DatabankProcess, tmp_path: Path,  # noqa: F811
) -> None:
    session, endpoint = hub
    db = tmp_path / "youbot.sqlite"
    shutil.copy(default_db_path("youbot"), db)
    target = Ecl.open("youbot").query("limb_11", "distal_11", "left-high", 3)
    with running_agent(endpoint, "youbot", "yb-capture") as (_, watch):
        op = CommandSender(session, "yb-capture")
        seq = op.send(("limb_11", "distal_11", "left-high", 3.0))
        state = watch.after(seq, lambda s: max(map(abs, s.qd)) < 1e-3 and s.status != "moving",
                            "youbot at rest at left-high")
        rc = main(["ecl", "record", "youbot", "--db", str(db), "--limb", "arm", "--origin",
                   "shoulder", "--direction", LIMB[2], "--size", str(LIMB[3]),
                   "--from-robot", "yb-capture", "--connect", endpoint])
        op.close()
    assert rc == 0
    stored = Ecl.open("youbot", db=db).query(*LIMB)
    reported = dict(zip(state.joint_names, state.q, strict=True))
    for joint, value in stored.joints.items():
        assert value == pytest.approx(reported[joint], abs=2e-3)
        assert value == pytest.approx(target.joints[joint], abs=2e-2)


def test_record_from_a_silent_robot_is_a_clear_error(
    hub: Hub, tmp_path: Path, capsys: pytest.CaptureFixture[str],  # noqa: F811
) -> None:
    db = tmp_path / "youbot.sqlite"
    shutil.copy(default_db_path("youbot"), db)
    before = db.read_bytes()
    rc = main(["ecl", "record", "youbot", "--db", str(db), "--limb", "arm", "--origin",
               "shoulder", "--direction", "forward-middle", "--size", "2",
               "--from-robot", "ghost", "--connect", hub[1], "--timeout", "0.5"])
    assert rc == 2
    assert "no state from robot 'ghost'" in capsys.readouterr().err
    assert db.read_bytes() == before
