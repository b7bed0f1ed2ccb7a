"""A fleet on loopback through a router, every role its own process (issue 7, test a).

``kinesphere router`` + databank + baxter, nao and youbot agents + scripted clients, all Zenoh
clients of the router, so every message crosses it. One scenario, in order: every robot
reaches its pose; the databank is SIGKILLed (robots keep running and holding their pose), a
new command while it is down is held, a restarted databank serves again and the command
works; a streaming ``kinesphere play`` is SIGKILLed and its robot stops within the TTL.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from kinesphere.keyexpr import KEYS
from kinesphere.procs import Supervisor
from kinesphere.protocol import Command, SpatialCommand, encode
from support.system import (
    Observer,
    at_pose,
    client_config,
    databank_args,
    query_pose,
    router_hub,
)
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes

ROBOTS = {"baxter-1": "baxter", "nao-1": "nao", "youbot-1": "youbot"}
POSE_A = ("limb_11", "distal_11", "right-high", 2)
POSE_B = ("limb_11", "distal_11", "forward-high", 2)
TTL_MS = 300
AGENT_HZ = "250"  # three real-time agents, a databank and a router share two cores in CI



def _send(sup: Supervisor, name: str, cfg: Path, pose: tuple[str, str, str, int]) -> None:
    child = sup.spawn(name, ["send", "all", *map(str, pose), "--zenoh-config", str(cfg),
                             "--wait", "20"], expect_exit=True)
    code = sup.wait(name, WAIT_S)
    assert code == 0, f"{name} exited {code}:\n{child.tail()}"


def _put(obs: Observer, pose: tuple[str, str, str, int], seq: int) -> None:
    """A command from the test's own session (a client of the router too)."""
    cmd = Command(seq=seq, sent_ns=time.time_ns(), parts=[SpatialCommand(*pose)], deadman=True,
                  ttl_ms=0, sender="test")
    obs.session.put(KEYS.command("*"), encode(cmd))


def test_fleet_through_router(tmp_path: Path, sup: Supervisor) -> None:
    dbs = databank_args(sorted(set(ROBOTS.values())))
    endpoint = router_hub(sup)  # the hub: it routes every put
    cfg = client_config(tmp_path / "client.json5", endpoint)

    obs = Observer(mode="client", connect=[endpoint])
    try:
        sup.spawn("databank", ["databank", "serve", *dbs, "--zenoh-config", str(cfg),
                               "--replica", "db-1"])
        for rid, platform in ROBOTS.items():
            sup.spawn(f"agent-{rid}", ["agent", platform, "--id", rid, "--zenoh-config", str(cfg),
                                       "--control-rate", AGENT_HZ])
        obs.wait_alive(set(ROBOTS), databank=True, sup=sup)
        a = {rid: query_pose(obs.session, p, *POSE_A).joints for rid, p in ROBOTS.items()}
        b = {rid: query_pose(obs.session, p, *POSE_B).joints for rid, p in ROBOTS.items()}

        # 1. a scripted client moves every robot to its own pose for the same command
        _send(sup, "send-a", cfg, POSE_A)
        until(lambda: all(at_pose(obs.states.last(r), a[r]) for r in ROBOTS), WAIT_S,
              "every robot at pose A", explain=lambda: f"{obs.describe()}\nwanted {a}")

        # 2. the databank dies: robots keep running and holding their pose
        sup.kill("databank")
        until(lambda: not obs.alive.databanks, WAIT_S, "the databank's token to go")
        killed_ns = time.time_ns()
        assert obs.states.wait_fresh(ROBOTS, killed_ns, WAIT_S), "robots stopped reporting"
        assert all(at_pose(obs.states.last(r), a[r]) and set(obs.alive.robots) >= set(ROBOTS)
                   for r in ROBOTS)

        # 3. a new command while it is down cannot be resolved: robots say so and hold
        _put(obs, POSE_B, seq=0)
        until(lambda: all(obs.state(r).status == "databank_unreachable"
                          for r in ROBOTS), WAIT_S, "robots to report databank_unreachable")
        assert all(at_pose(obs.states.last(r), a[r]) for r in ROBOTS)

        # 4. a restarted databank serves again, without restarting anything else
        sup.spawn("databank", ["databank", "serve", *dbs, "--zenoh-config", str(cfg),
                               "--replica", "db-2"])
        until(lambda: "db-2" in obs.alive.databanks, WAIT_S, "databank back", guard=sup.check)
        _put(obs, POSE_B, seq=1)
        until(lambda: all(at_pose(obs.states.last(r), b[r]) for r in ROBOTS), WAIT_S,
              "every robot at pose B after the restart",
              explain=lambda: f"{obs.describe()}\nwanted {b}")

        # 5. a streaming client is killed: its robot stops within the TTL
        phrase = tmp_path / "drive.toml"
        phrase.write_text(f'name = "drive"\nttl_ms = {TTL_MS}\n[[step]]\nduration = 120\n'
                          'parts = []\ndrive = "forward 0.5"\n')
        sup.spawn("play", ["play", str(phrase), "--target", "youbot-1", "--zenoh-config",
                           str(cfg), "--wait", "20"])
        x0 = obs.state("youbot-1").base_pose[0]
        until(lambda: obs.state("youbot-1").base_pose[0] > x0 + 0.05, WAIT_S,
              "the youbot to drive", guard=sup.check)
        sup.kill("play")
        killed = time.monotonic()
        until(lambda: obs.state("youbot-1").status == "holding", 10.0,
              "the youbot to hold")
        to_hold = time.monotonic() - killed
        assert to_hold < TTL_MS / 1000 + 1.5, f"held {to_hold:.2f} s after the client died"

        # and its base comes to rest (it brakes jerk-limited from where the TTL caught it)
        x = obs.state("youbot-1").base_pose[0]
        while True:
            assert obs.states.wait_fresh(["youbot-1"], time.time_ns() + 200_000_000, 5.0)
            x, dx = obs.state("youbot-1").base_pose[0], x
            if abs(x - dx) < 0.002:
                break
            assert time.monotonic() - killed < TTL_MS / 1000 + 5.0, "the base did not stop"
        print(f"client killed: holding after {to_hold:.2f} s, "
              f"base at rest after {time.monotonic() - killed:.2f} s")
    finally:
        obs.close()
