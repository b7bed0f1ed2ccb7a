"""The agent and the databank's life: outages, recovery, and poses recorded while it runs.

These use their own hub and databank process (the other tests share one): they stop it, or
write to it.
"""

from __future__ import annotations

import shutil
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from kinesphere import zconfig
from kinesphere.protocol import RecordRequest, SpatialCommand, encode
from kinesphere.robots.agent.resolver import Resolver
from kinesphere.services.ecl.store import DATA_DIR
from support.agents import (
    CommandSender,
    DatabankProcess,
    databank_on,
    joints_close,
    real_pulls,
    running_agent,
)
from support.network import KEYS, Hub
from support.wait import WAIT_S, until

pytestmark = pytest.mark.processes


@pytest.fixture
def own_hub() -> Iterator[Hub]:
    """Not the shared hub: the shared databank must not answer while this one is down."""
    with zconfig.loopback_hub() as pair:
        yield Hub(*pair)


@pytest.fixture
def own_databank(own_hub: Hub) -> Iterator[DatabankProcess]:
    with databank_on(own_hub) as bank:
        yield bank


def test_outage_keeps_last_pose_and_recovers_without_restart(
    own_hub: Hub, own_databank: DatabankProcess
) -> None:
    session, endpoint = own_hub
    entry = own_databank.catalogue("baxter").limbs[0]
    pulls = real_pulls(entry)
    first = SpatialCommand(entry.limb, entry.origin, pulls[0], 2.0)
    second = SpatialCommand(entry.limb, entry.origin, pulls[-1], 2.0)
    pose1, pose2 = own_databank.query("baxter", first), own_databank.query("baxter", second)
    with (running_agent(endpoint, "baxter", speed=4.0) as (agent, watch),
          CommandSender(session, agent.robot_id) as op):
        target1, _ = agent.controller.joints.clamp(pose1.joints)
        target2, _ = agent.controller.joints.clamp(pose2.joints)
        seq = op.send(first)
        watch.after(seq, lambda s: s.status == "idle" and joints_close(s, target1, 5e-3),
                    "at the first pose")

        own_databank.stop()
        seq = op.send(second)
        down = watch.after(seq, lambda s: s.status == "databank_unreachable",
                           "outage reported")
        assert joints_close(down, target1, 5e-3), "keeps its last pose"
        assert not agent.controller.moving

        # a pose it already knows still works while the databank is away (cached)
        seq = op.send(first)
        watch.after(seq, lambda s: joints_close(s, target1, 5e-3), "cached pose during outage")

        own_databank.start()
        watch.wait(lambda s: s.status not in ("databank_unreachable", "error"),
                   "recovered without a new command")
        seq = op.send(second)
        watch.after(seq, lambda s: s.status == "idle" and joints_close(s, target2, 5e-3),
                    "the second pose after recovery")


def test_cache_is_per_databank_version(
    own_hub: Hub, tmp_path: Path
) -> None:
    """A repeated command needs no round trip; a recorded pose reaches the robot at once."""
    session, endpoint = own_hub
    db = tmp_path / "youbot.sqlite"
    shutil.copy(DATA_DIR / "youbot.sqlite", db)
    bank = DatabankProcess(endpoint, session, ["--db", f"youbot={db}", "--allow-writes"])
    bank.start()
    try:
        entry = bank.catalogue("youbot").limbs[0]
        direction = real_pulls(entry)[0]
        part = (entry.limb, entry.origin, direction, 2.0)
        old = bank.query("youbot", SpatialCommand(*part))
        with (running_agent(endpoint, "youbot", speed=4.0) as (agent, watch),
              CommandSender(session, agent.robot_id) as op):
            for _ in range(3):
                seq = op.send(part)
                watch.after(seq, lambda s: s.status == "idle"
                            and joints_close(s, old.joints, 5e-3), "at the stored pose")
            assert agent.resolver.queries == 1, "repeats are answered from the cache"
            version = agent.resolver.version

            new = {j: v + (0.2 if v < 0.5 else -0.2) for j, v in old.joints.items()}
            request = RecordRequest(limb=part[0], origin=part[1], direction=direction, size=2,
                                    joints=new)
            replies = list(session.get(KEYS.record("youbot"), payload=encode(request),
                                       timeout=WAIT_S))
            assert replies and replies[0].ok is not None, "recorded"
            # the record's reply and its `changed` announcement travel on different links:
            # the robot forgets its cache when the announcement arrives, not before
            until(lambda: agent.resolver.version != version, WAIT_S, "the robot told")
            seq = op.send(part)
            watch.after(seq, lambda s: s.status == "idle" and joints_close(s, new, 5e-3),
                        "at the newly recorded pose")
            assert agent.resolver.version != version
            assert agent.resolver.queries == 2
    finally:
        bank.stop()


def test_a_robot_stopped_while_no_databank_answers_stops_at_once(own_hub: Hub) -> None:
    """Its resolver waits for a databank to turn up (``ready_s``); closing it ends that wait,
    so its worker has ended when ``close`` returns (it used to run out ``ready_s`` while close
    gave up joining it)."""
    with zconfig.session(config=zconfig.loopback_config(own_hub.endpoint)) as s:
        resolver = Resolver(s, "limbo", KEYS, ready_s=WAIT_S)
        resolver.start()
        resolver.close()
        assert "resolver-limbo" not in [t.name for t in threading.enumerate()]
        assert resolver.reachable is None, "it never asked a databank"
