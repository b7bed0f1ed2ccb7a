"""The robot status table printed by ``kinesphere up`` and ``kinesphere status``."""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Mapping
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from kinesphere.protocol import RobotState
from kinesphere.words import degrees, signed

STYLE = {
    "idle": "green",
    "moving": "cyan",
    "holding": "yellow",
    "stopped": "yellow",
    "clamped": "magenta",
    "estop": "bold red",
    "databank_unreachable": "red",
    "error": "bold red",
}


def _age(state: RobotState, now_ns: int) -> str:
    return f"{max(0.0, (now_ns - state.stamp_ns) / 1e9):.1f}s"


def robot_table(
    states: Mapping[str, RobotState],
    alive: Iterable[str] = (),
    databanks: Iterable[str] = (),
    title: str = "kinesphere robots",
) -> Table:
    """One row per robot seen (live token, state, or both); missing state shows as '-'.
    Names and details come from the network: shown as text, never read as rich markup. A
    detail wraps at words, whole (a release it names stays a command that runs)."""
    now = time.time_ns()
    live = set(alive)
    dbs = sorted(databanks)
    caption = escape(f"databanks: {', '.join(dbs) if dbs else 'none alive'}")
    table = Table(title=title, caption=caption, expand=False)
    for col in ("robot", "platform", "status", "last cmd", "base x, y, yaw", "max |qd|",
                "age", "detail"):
        table.add_column(col, no_wrap=col != "detail", overflow="fold" if col == "detail"
                         else "ellipsis")
    for rid in sorted(set(states) | live):
        st = states.get(rid)
        mark = "" if rid in live or not live else " (no token)"
        if st is None:
            table.add_row(escape(rid + mark), "-", "[dim]no state yet[/]", "-", "-", "-", "-", "")
            continue
        qd = max((abs(v) for v in st.qd), default=0.0)
        x, y, yaw = st.base_pose
        table.add_row(
            escape(rid + mark),
            escape(st.platform),
            f"[{STYLE.get(st.status, 'white')}]{escape(st.status)}[/]",
            str(st.last_command_seq) if st.last_command_seq >= 0 else "none",
            f"{signed(x)}, {signed(y)}, {degrees(yaw)}",
            f"{qd:.3f}",
            _age(st, now),
            escape(st.detail),
        )
    return table


def state_dict(st: RobotState) -> dict[str, Any]:
    """A JSON-ready view of a state (for ``--json`` and the demo summary)."""
    return {
        "robot_id": st.robot_id,
        "platform": st.platform,
        "status": st.status,
        "detail": st.detail,
        "seq": st.seq,
        "stamp_ns": st.stamp_ns,
        "last_command_seq": st.last_command_seq,
        "base_pose": list(st.base_pose),
        "joints": dict(zip(st.joint_names, st.q, strict=True)),
        "max_qd": max((abs(v) for v in st.qd), default=0.0),
        "clamped": list(st.clamped),
    }


def wide_console() -> Console:
    """A console; when output is not a terminal (make demo, CI logs), wide enough for tables."""
    console = Console(log_path=False)
    if not console.is_terminal and "COLUMNS" not in os.environ:
        console = Console(width=140, log_path=False)
    return console
