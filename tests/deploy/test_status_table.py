"""The status table of ``kinesphere status`` and ``up``: what robots say is shown as they said
it (rich markup in a name or detail is text, not a crash), and a long detail wraps whole."""

from __future__ import annotations

import io
import time

from rich.console import Console

from kinesphere.deploy.table import robot_table
from kinesphere.protocol import RobotState


def state(robot_id: str, detail: str, status: str = "idle") -> RobotState:
    return RobotState(robot_id=robot_id, platform="youbot", seq=1, stamp_ns=time.time_ns(),
                      joint_names=[], q=[], qd=[], base_pose=[0.0, 0.0, 0.0], status=status,
                      last_command_seq=0, detail=detail)


def shown(states: dict[str, RobotState], databanks: list[str]) -> str:
    console = Console(width=200, record=True, file=io.StringIO())
    console.print(robot_table(states, alive=states, databanks=databanks))
    return console.export_text()


def test_markup_from_the_network_is_shown_as_text() -> None:
    text = shown({"r[bold]1": state("r[bold]1", "oops [/bold] [red]x", status="[b]idle")},
                 ["db[red]"])  # before: rich.errors.MarkupError, no table
    assert "r[bold]1" in text and "oops [/bold] [red]x" in text and "[b]idle" in text
    assert "databanks: db[red]" in text


def test_a_long_detail_wraps_whole_at_words() -> None:
    """Before: cut mid-word at 60 characters (``release=tru``)."""
    detail = "e-stop from ada@lab; release with a command with release=true " * 2
    text = shown({"yb-1": state("yb-1", detail, status="estop")}, [])
    cells = [line.split("│")[-2].split() for line in text.splitlines() if line.count("│") > 2]
    assert [w for cell in cells for w in cell] == detail.split()
