"""The status table of ``kinesphere status`` and ``up`` says what robots said, in whole words:
a detail wraps instead of being cut, no robot is at ``-0°``, a robot that acted on no command
says so rather than ``-1``."""

from __future__ import annotations

import math
import time

from rich.console import Console

from kinesphere.deploy.table import robot_table
from kinesphere.protocol import RobotState


def state(**kw: object) -> RobotState:
    base: dict[str, object] = dict(
        robot_id="yb-1", platform="youbot", seq=1, stamp_ns=time.time_ns(), joint_names=["a"],
        q=[0.0], qd=[0.0], base_pose=[-1e-4, 0.0, -1e-4], status="estop", last_command_seq=-1,
        detail="e-stop from alice; release with 'kinesphere estop --release --target yb-1 "
               "--sender alice'")
    base.update(kw)
    return RobotState(**base)  # type: ignore[arg-type]


def printed(*states: RobotState, width: int = 100) -> str:
    console = Console(width=width, record=True, color_system=None)
    console.print(robot_table({s.robot_id: s for s in states}, alive=[s.robot_id for s in states]))
    return console.export_text()


def test_details_wrap_whole_and_numbers_read_right() -> None:
    text = printed(state(), state(robot_id="yb-2", last_command_seq=12,
                                  base_pose=[1.0, 2.0, math.pi / 2]))
    detail = state().detail
    cells = [line.split("│")[-2].split() for line in text.splitlines() if line.count("│") > 2]
    shown = [w for cell in cells for w in cell]
    assert shown == detail.split() * 2, "every word of each detail, whole, in order"
    assert "-0°" not in text and "+0°" in text and "+90°" in text
    assert "-0.00" not in text and "+0.00, +0.00" in text
    rows = {line.split("│")[1].strip(): [c.strip() for c in line.split("│")[1:-1]]
            for line in text.splitlines() if line.startswith("│ yb")}
    assert rows["yb-1"][3] == "none" and rows["yb-2"][3] == "12"
