"""``kinesphere status``: who is alive on a kinesphere network and what each robot last said.

Liveliness answers "which processes exist" at once; a robot's state stream answers "what is
it doing". The state subscription ends as soon as every live robot has reported (or at the
timeout), so a healthy system answers in well under a second.
"""

from __future__ import annotations

import json
import time
from typing import Any

import zenoh
from rich.console import Console

from kinesphere.deploy.table import robot_table, state_dict, wide_console
from kinesphere.deploy.watch import StateRecorder, query_alive
from kinesphere.keyexpr import Keys


def collect(session: zenoh.Session, keys: Keys, timeout: float) -> dict[str, Any]:
    """Liveliness plus each robot's last state, as a JSON-ready dict."""
    recorder = StateRecorder(keys, history=False)
    deadline = time.monotonic() + timeout
    recorder.start(session)
    try:
        databanks, robots = query_alive(session, keys, timeout)
        left = max(0.05, deadline - time.monotonic())
        recorder.wait_for(lambda st: set(robots) <= set(st), left if robots else 0.3)
    finally:
        recorder.close()
    states = recorder.snapshot()
    return {
        "databanks": databanks,
        "robots": {
            rid: {"alive": rid in robots,
                  "state": state_dict(states[rid]) if rid in states else None}
            for rid in sorted(set(robots) | set(states))
        },
        "_states": states,
    }


def print_status(info: dict[str, Any], as_json: bool, console: Console | None = None) -> int:
    """Print ``info``; exit code 0 when something is alive, 1 when nothing answered."""
    states = info.pop("_states", {})
    if as_json:
        print(json.dumps(info, indent=2))
    else:
        alive = [rid for rid, r in info["robots"].items() if r["alive"]]
        (console or wide_console()).print(
            robot_table(states, alive=alive, databanks=info["databanks"], title="kinesphere status")
        )
    return 0 if info["databanks"] or info["robots"] else 1
