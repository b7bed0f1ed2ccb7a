"""``kinesphere status``: who is alive on a kinesphere network and what each robot last said.

Liveliness says which processes exist, a robot's state stream what it is doing. Both are
subscribed to from the start, liveliness with history, and status answers once discovery has
settled: every robot whose token arrived has also reported, and nothing new turned up for
``zconfig.QUIET_S``. A client of the router (the default) hears everything through it at
once; a peer first has to link to the others its gossip names, so in peer mode status waits
at least ``zconfig.discovery_time``. One liveliness query
answered at once, as before, missed robots a peer had not linked to yet (5 of 10 runs).
"""

from __future__ import annotations

import json
import time
from typing import Any

import zenoh
from rich.console import Console

from kinesphere.deploy.table import robot_table, state_dict, wide_console
from kinesphere.deploy.watch import StateRecorder, watch_alive
from kinesphere.keyexpr import Keys
from kinesphere.zconfig import QUIET_S, discovery_time, undeclare


def collect(session: zenoh.Session, keys: Keys, timeout: float) -> dict[str, Any]:
    """Liveliness plus each robot's last state, as a JSON-ready dict, once discovery settled
    (not before :func:`~kinesphere.zconfig.discovery_time`) or at ``timeout``."""
    start = time.monotonic()
    deadline = start + timeout
    earliest = start + discovery_time(session)
    recorder = StateRecorder(keys, history=False).start(session)
    alive, subs = watch_alive(session, keys)
    seen: set[str] = set()
    changed = start
    try:
        while True:
            now = time.monotonic()
            states = recorder.snapshot()
            with alive.changed:
                robots, databanks = set(alive.robots), set(alive.databanks)
            found = {f"r:{r}" for r in robots | set(states)} | {f"d:{d}" for d in databanks}
            if found - seen:
                seen |= found
                changed = now
            settled = (found and robots <= set(states) and now - changed >= QUIET_S
                       and now >= earliest)
            if settled or now >= deadline:
                break
            # a state arrives every few ms from each robot; wake at least every 50 ms
            recorder.wait_for(lambda _s: False, min(0.05, max(0.0, deadline - now)))
    finally:
        undeclare(*subs)
        recorder.close()
    states = recorder.snapshot()
    return {
        "databanks": sorted(databanks),
        "robots": {
            rid: {"alive": rid in robots,
                  "state": state_dict(states[rid]) if rid in states else None}
            for rid in sorted(robots | set(states))
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
