"""A process told only to connect listens nowhere (client) or on loopback only (peer).

Before: ``kinesphere agent khepera --connect tcp/127.0.0.1:X`` listened on ``*:<port>`` in
plain TCP (Zenoh's peer default), and a client connecting straight there drove the base past
the router and its access control; ``databank serve --connect`` did the same.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from test_system_support import (
    WAIT_S,
    Observer,
    databank_args,
    listeners,
    loopback,
    supervisor,
    until,
)

from kinesphere.deploy.procs import Supervisor
from kinesphere.zconfig import loopback_config, loopback_hub


@pytest.fixture(scope="module")
def hub() -> Iterator[str]:
    with loopback_hub() as (_session, endpoint):
        yield endpoint


@pytest.fixture(scope="module")
def sup(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Supervisor]:
    yield from supervisor(tmp_path_factory.mktemp("listeners") / "logs")


def test_connect_only_processes_never_listen_beyond_loopback(hub: str, sup: Supervisor,
                                                             tmp_path: Path) -> None:
    dbs = databank_args(["khepera"])
    sup.spawn("agent-peer", ["agent", "khepera", "--id", "kpeer", "--connect", hub])
    sup.spawn("agent-client", ["agent", "khepera", "--id", "kclient", "--connect", hub,
                               "--mode", "client"])
    sup.spawn("databank-peer", ["databank", "serve", *dbs, "--replica", "dpeer",
                                "--connect", hub])
    sup.spawn("databank-client", ["databank", "serve", *dbs, "--replica", "dclient",
                                  "--connect", hub, "--mode", "client"])
    obs = Observer(loopback_config(hub))
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
