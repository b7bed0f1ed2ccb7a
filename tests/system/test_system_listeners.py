"""A process told only to connect listens nowhere (client) or on loopback only (peer).

Before: ``kinesphere agent khepera --connect tcp/127.0.0.1:X`` listened on ``*:<port>`` in
plain TCP (Zenoh's peer default), and a client connecting straight there drove the base past
the router and its access control; ``databank serve --connect`` did the same.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from kinesphere.procs import Supervisor
from kinesphere.zconfig import loopback_config
from support.network import Hub
from support.system import Observer, databank_args, listeners, loopback
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes


def test_connect_only_processes_never_listen_beyond_loopback(hub: Hub, sup: Supervisor,
                                                             tmp_path: Path) -> None:
    endpoint = hub.endpoint
    dbs = databank_args(["khepera"])
    sup.spawn("agent-peer", ["agent", "khepera", "--id", "kpeer", "--connect", endpoint])
    sup.spawn("agent-client", ["agent", "khepera", "--id", "kclient", "--connect", endpoint,
                               "--mode", "client"])
    sup.spawn("databank-peer", ["databank", "serve", *dbs, "--replica", "dpeer",
                                "--connect", endpoint])
    sup.spawn("databank-client", ["databank", "serve", *dbs, "--replica", "dclient",
                                  "--connect", endpoint, "--mode", "client"])
    obs = Observer(loopback_config(endpoint))
    try:
        obs.wait_alive({"kpeer", "kclient"}, databank=True, sup=sup)
        until(lambda: {"dpeer", "dclient"} <= obs.alive.databanks, WAIT_S,
              "both databanks' liveliness")
    finally:
        obs.close()
    found = {name: listeners(sup.children[name].pid) for name in sup.children}
    assert found["agent-client"] == [] and found["databank-client"] == [], found
    assert found["agent-peer"] and loopback(found["agent-peer"]), found
    assert found["databank-peer"] and loopback(found["databank-peer"]), found
