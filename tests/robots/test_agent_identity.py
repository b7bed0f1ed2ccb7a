"""One robot per id: a second agent with a live id refuses to start (exit 2, naming where the
other runs), also two agents claiming it at the same moment; the id is free again when the
first leaves. Real Zenoh, real agents (in this process and as ``kinesphere agent``)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading

import pytest

from kinesphere import zconfig
from kinesphere.errors import KinesphereError
from kinesphere.robots.agent.presence import Claim
from kinesphere.robots.agent.runtime import Agent, AgentOptions
from support.agents import running_agent
from support.network import KEYS, Hub
from support.paths import ROOT
from support.wait import WAIT_S


def test_a_second_agent_with_a_live_id_refuses_naming_the_first(hub: Hub) -> None:
    with running_agent(hub.endpoint, "youbot", "twin"):
        with zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as s:
            second = Agent("khepera", "twin", s, AgentOptions())
            try:
                with pytest.raises(KinesphereError) as refused:
                    second.declare()
            finally:
                second.close()
    assert refused.value.code == "id_taken"
    host = socket.gethostname().split(".")[0]
    assert (f"robot id 'twin' is already running: youbot on host {host} (pid {os.getpid()})"
            in refused.value.message)
    assert "give this robot another --id" in refused.value.message
    with running_agent(hub.endpoint, "khepera", "twin") as (_, watch):  # free again
        assert watch.wait(lambda st: True, "a state").platform == "khepera"


def test_two_agents_claiming_one_id_at_once_leave_one(hub: Hub) -> None:
    """Both ask, both declare, both ask again: the later claim gives way."""
    outcomes: list[str] = []
    claims: list[Claim] = []
    barrier = threading.Barrier(2)
    with zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as a, \
            zconfig.session(config=zconfig.loopback_config(hub.endpoint)) as b:

        def claim(s: object, platform: str) -> None:
            c = Claim(s, KEYS, "race", platform)  # type: ignore[arg-type]
            barrier.wait()
            try:
                c.take()
                claims.append(c)
                outcomes.append("ran")
            except KinesphereError as exc:
                outcomes.append(exc.code)

        threads = [threading.Thread(target=claim, args=(s, p))
                   for s, p in ((a, "youbot"), (b, "nao"))]
        for t in threads:
            t.start()
        for t in threads:
            t.join(WAIT_S)
        for c in claims:
            c.release()
    assert sorted(outcomes) == ["id_taken", "ran"], outcomes


@pytest.mark.processes
def test_the_command_exits_2_and_the_id_is_free_when_the_first_leaves(hub: Hub) -> None:
    def agent(*extra: str) -> subprocess.Popen[str]:
        return subprocess.Popen(
            [sys.executable, "-m", "kinesphere.cli", "agent", "youbot", "--id", "yb-dup",
             "--connect", hub.endpoint, "--listen", zconfig.LOOPBACK_ANY_PORT, *extra],
            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)

    alive = threading.Event()
    token = hub.session.liveliness().declare_subscriber(
        KEYS.alive_robot("yb-dup"), lambda s: alive.set(), history=True)
    first = agent()
    try:
        assert alive.wait(WAIT_S), "the first agent is up"
        second = agent()
        out, _ = second.communicate(timeout=WAIT_S)
        assert second.returncode == 2, out
        assert "robot id 'yb-dup' is already running: youbot on host " in out
        assert f"(pid {first.pid})" in out and "[id_taken]" in out
    finally:
        first.send_signal(signal.SIGTERM)
        first.communicate(timeout=WAIT_S)
        zconfig.undeclare(token)
    third = agent()
    try:
        alive.clear()
        token = hub.session.liveliness().declare_subscriber(
            KEYS.alive_robot("yb-dup"), lambda s: alive.set(), history=True)
        assert alive.wait(WAIT_S), "the id is free once the first left"
    finally:
        third.send_signal(signal.SIGTERM)
        assert third.wait(WAIT_S) == 0
        zconfig.undeclare(token)
