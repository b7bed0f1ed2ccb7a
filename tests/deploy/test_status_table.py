"""The status table of ``kinesphere status`` and ``up``: what robots say is shown as they said
it (rich markup in a name or detail is text, not a crash), and a long detail says it was cut."""

from __future__ import annotations

import io
import time

from rich.console import Console

from kinesphere.deploy.table import DETAIL_CHARS, robot_table
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


def test_a_long_detail_is_cut_at_a_word_and_says_so() -> None:
    detail = "e-stop from ada@lab; release with a command with release=true"
    assert len(detail) > DETAIL_CHARS
    text = shown({"yb-1": state("yb-1", detail, status="estop")}, [])
    assert "e-stop from ada@lab; release with a command with…" in text
    assert "release=tru" not in text
