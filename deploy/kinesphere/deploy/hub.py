"""The hub of a local system: a ``kinesphere router`` process that serves nothing else.

Whatever every other process connects to must outlive them all. A databank (or the
supervisor) as the hub made it a single point of failure: killed, no command and no e-stop
reached any robot. A router holds no state and runs no service, so any service process can be
killed -9 and the others keep talking; they join it as Zenoh clients, so every message
crosses it (as in ``deploy/``).
"""

from __future__ import annotations

import time
from typing import Final

import zenoh

from kinesphere.errors import KinesphereError
from kinesphere.procs import ChildFailed, Supervisor
from kinesphere.zconfig import loopback_endpoint, open_session, session_config

ATTEMPTS: Final = 5
"""Free ports tried: another process may take a probed port before the router binds it."""


def client_args(endpoint: str) -> list[str]:
    """The zenoh options of a child joining the hub at ``endpoint``."""
    return ["--connect", endpoint, "--mode", "client"]


def start_hub(sup: Supervisor, timeout: float, name: str = "router"
              ) -> tuple[str, zenoh.Session]:
    """Start the router child ``name`` on a free loopback port; returns its endpoint and a
    client session joined to it (opening that session is how we know the router is up)."""
    last = ""
    for _ in range(ATTEMPTS):
        endpoint = loopback_endpoint()
        child = sup.spawn(name, ["router", "--listen", endpoint], expect_exit=True)
        config = session_config("client", connect=[endpoint], listen=[], scouting=False)
        deadline = time.monotonic() + timeout
        while child.alive():
            try:
                session = open_session(config=config)
            except KinesphereError as exc:
                last = exc.message
                if time.monotonic() > deadline:
                    sup.stop(name)
                    raise KinesphereError(
                        "unavailable", f"the router on {endpoint} accepted nobody within "
                        f"{timeout:g} s: {last}\n{child.tail()}") from None
                time.sleep(0.05)  # retrying the connection is the wait; nothing to await
                continue
            sup.expected_exit.discard(name)  # from now on, a dead router is a failure
            return endpoint, session
        last = child.tail()  # the port was taken: try another
    raise ChildFailed(f"the router could not start on a free port:\n{last}")
